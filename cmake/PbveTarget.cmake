# pbve_add_library(<target> ALIAS <name> SOURCES <files...>)
# Creates library <target> with alias pbve::<name> (export name <name>), pbve's include
# directories and warnings, and registers it for install/export.
function(pbve_add_library target)
  cmake_parse_arguments(ARG "" "ALIAS" "SOURCES" ${ARGN})
  add_library(${target} ${ARG_SOURCES})
  add_library(pbve::${ARG_ALIAS} ALIAS ${target})
  set_target_properties(${target} PROPERTIES EXPORT_NAME ${ARG_ALIAS} OUTPUT_NAME pbve_${ARG_ALIAS}
                                             VERSION ${PROJECT_VERSION} SOVERSION ${PROJECT_VERSION_MAJOR}.${PROJECT_VERSION_MINOR})
  target_compile_features(${target} PUBLIC cxx_std_20)
  target_include_directories(${target} PUBLIC
    $<BUILD_INTERFACE:${PROJECT_SOURCE_DIR}/include>
    $<BUILD_INTERFACE:${PROJECT_BINARY_DIR}/include>
    $<INSTALL_INTERFACE:${CMAKE_INSTALL_INCLUDEDIR}>)
  target_include_directories(${target} PRIVATE ${PROJECT_SOURCE_DIR}/src)
  target_link_libraries(${target} PRIVATE $<BUILD_INTERFACE:pbve_warnings>)
  set_property(GLOBAL APPEND PROPERTY PBVE_EXPORT_TARGETS ${target})
endfunction()
