# Install + export so that another project can find_package(pbve) and link pbve::core.
include(CMakePackageConfigHelpers)

install(DIRECTORY ${PROJECT_SOURCE_DIR}/include/pbve DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}
        FILES_MATCHING PATTERN "*.hpp")
install(FILES ${PROJECT_BINARY_DIR}/include/pbve/config.hpp
        DESTINATION ${CMAKE_INSTALL_INCLUDEDIR}/pbve)

get_property(pbve_export_targets GLOBAL PROPERTY PBVE_EXPORT_TARGETS)
install(TARGETS ${pbve_export_targets} EXPORT pbveTargets
        ARCHIVE DESTINATION ${CMAKE_INSTALL_LIBDIR}
        LIBRARY DESTINATION ${CMAKE_INSTALL_LIBDIR}
        RUNTIME DESTINATION ${CMAKE_INSTALL_BINDIR}
        INCLUDES DESTINATION ${CMAKE_INSTALL_INCLUDEDIR})
install(EXPORT pbveTargets NAMESPACE pbve:: DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbve)

configure_package_config_file(${PROJECT_SOURCE_DIR}/cmake/pbveConfig.cmake.in
  ${PROJECT_BINARY_DIR}/pbveConfig.cmake INSTALL_DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbve)
write_basic_package_version_file(${PROJECT_BINARY_DIR}/pbveConfigVersion.cmake
  VERSION ${PROJECT_VERSION} COMPATIBILITY SameMinorVersion)
install(FILES ${PROJECT_BINARY_DIR}/pbveConfig.cmake ${PROJECT_BINARY_DIR}/pbveConfigVersion.cmake
              ${PROJECT_SOURCE_DIR}/cmake/PbveCholmod.cmake
        DESTINATION ${CMAKE_INSTALL_LIBDIR}/cmake/pbve)

# pbve.pc, for builds without CMake: `pkg-config --cflags --libs pbve` (add --static for static
# pbve libraries, whose private dependencies then come along).
set(PBVE_PC_LIBS "")
foreach(t engines mass_spring bullet)
  if(TARGET pbve_${t})
    string(APPEND PBVE_PC_LIBS "-lpbve_${t} ")
  endif()
endforeach()
string(APPEND PBVE_PC_LIBS "-lpbve_core")
set(PBVE_PC_REQUIRES_PRIVATE "")
set(PBVE_PC_LIBS_PRIVATE "")
if(NOT BUILD_SHARED_LIBS)
  # Embree 3 and Debian 12's CHOLMOD have no pkg-config file.
  set(PBVE_PC_REQUIRES_PRIVATE "tbb nlopt ipopt yaml-cpp")
  set(PBVE_PC_LIBS_PRIVATE "-lembree3 -lcholmod")
  if(TARGET pbve_bullet)
    string(APPEND PBVE_PC_REQUIRES_PRIVATE " bullet-float64")
  endif()
endif()
if(IS_ABSOLUTE "${CMAKE_INSTALL_LIBDIR}" OR IS_ABSOLUTE "${CMAKE_INSTALL_INCLUDEDIR}")
  message(STATUS "pbve.pc not installed: CMAKE_INSTALL_LIBDIR and CMAKE_INSTALL_INCLUDEDIR must be relative")
else()
  # From <prefix>/<libdir>/pkgconfig back to <prefix>: one ".." per component.
  string(REGEX REPLACE "[^/]+" ".." PBVE_PC_PREFIX_FROM_PCDIR "${CMAKE_INSTALL_LIBDIR}/pkgconfig")
  configure_file(${PROJECT_SOURCE_DIR}/cmake/pbve.pc.in ${PROJECT_BINARY_DIR}/pbve.pc @ONLY)
  install(FILES ${PROJECT_BINARY_DIR}/pbve.pc DESTINATION ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
endif()
