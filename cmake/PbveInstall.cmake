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
