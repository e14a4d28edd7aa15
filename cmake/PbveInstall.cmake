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

# pbve.pc, for builds without CMake: `c++ -std=c++20 app.cpp $(pkg-config --cflags --libs pbve)`
# (add --static for static pbve libraries, whose private dependencies then come along).
set(PBVE_PC_LIBS "")
foreach(t engines mass_spring bullet)
  if(TARGET pbve_${t})
    string(APPEND PBVE_PC_LIBS "-lpbve_${t} ")
  endif()
endforeach()
string(APPEND PBVE_PC_LIBS "-lpbve_core")
# A static pbve's private dependencies as link flags (not Requires.private, whose compile flags
# pkg-config would pass to every program: Bullet's double precision among them). Embree 3 and
# Debian 12's CHOLMOD have no pkg-config file.
set(PBVE_PC_LIBS_PRIVATE "")
if(NOT BUILD_SHARED_LIBS)
  set(pc_private embree3 tbb nlopt ${IPOPT_LIBRARIES} yaml-cpp cholmod)
  if(TARGET pbve_bullet)
    list(APPEND pc_private ${BULLET_LIBRARIES})
  endif()
  list(TRANSFORM pc_private PREPEND -l)
  list(REMOVE_DUPLICATES pc_private)
  list(JOIN pc_private " " PBVE_PC_LIBS_PRIVATE)
endif()
# Relocatable (paths from the file's own folder) when the library and include folders are
# relative to the prefix; absolute install folders are written as they are, with the prefix of
# the configuration (as CMake's exported targets hold it then): such a tree is not relocatable.
if(IS_ABSOLUTE "${CMAKE_INSTALL_LIBDIR}")
  set(PBVE_PC_PREFIX "${CMAKE_INSTALL_PREFIX}")
  set(PBVE_PC_LIBDIR "${CMAKE_INSTALL_LIBDIR}")
else()
  file(RELATIVE_PATH pc_up "/pbve_root/${CMAKE_INSTALL_LIBDIR}/pkgconfig" "/pbve_root")
  string(REGEX REPLACE "/$" "" pc_up "${pc_up}")
  set(PBVE_PC_PREFIX "\${pcfiledir}/${pc_up}")
  set(PBVE_PC_LIBDIR "\${prefix}/${CMAKE_INSTALL_LIBDIR}")
endif()
if(IS_ABSOLUTE "${CMAKE_INSTALL_INCLUDEDIR}")
  set(PBVE_PC_INCLUDEDIR "${CMAKE_INSTALL_INCLUDEDIR}")
else()
  set(PBVE_PC_INCLUDEDIR "\${prefix}/${CMAKE_INSTALL_INCLUDEDIR}")
endif()
# The dependencies' header folders as system headers, as CMake consumers get them: GCC then
# ignores the same folder's -I from their own pkg-config files (OpenCV 4.6's headers give C++20
# deprecation warnings in any program that includes them otherwise). The compiler's own folders
# are left out (-isystem /usr/include would break the standard library's #include_next).
set(PBVE_PC_SYSTEM_CFLAGS "")
get_target_property(pc_eigen_dirs Eigen3::Eigen INTERFACE_INCLUDE_DIRECTORIES)
foreach(dir IN LISTS OpenCV_INCLUDE_DIRS pc_eigen_dirs)
  if(dir AND NOT dir MATCHES "[$]<" AND NOT dir IN_LIST CMAKE_CXX_IMPLICIT_INCLUDE_DIRECTORIES
     AND NOT dir MATCHES "^/usr(/local)?/include/?$")
    string(APPEND PBVE_PC_SYSTEM_CFLAGS " -isystem ${dir}")
  endif()
endforeach()
configure_file(${PROJECT_SOURCE_DIR}/cmake/pbve.pc.in ${PROJECT_BINARY_DIR}/pbve.pc @ONLY)
install(FILES ${PROJECT_BINARY_DIR}/pbve.pc DESTINATION ${CMAKE_INSTALL_LIBDIR}/pkgconfig)
