# terramap_add_plugin(<name> SOURCES <src>... [LIBRARIES <lib>...] [NO_INSTALL])
#
# Builds a terramap plugin: a shared library named <name> (no "lib" prefix) with hidden
# visibility, linked to terramap::plugin_api, placed where the host looks for plugins
# (<libdir>/terramap/plugins in the build tree and in the install tree).
# The same function serves in-tree plugins and out-of-tree ones (find_package(terramap)).
function(terramap_add_plugin name)
  cmake_parse_arguments(ARG "NO_INSTALL" "" "SOURCES;LIBRARIES" ${ARGN})
  if(NOT ARG_SOURCES)
    message(FATAL_ERROR "terramap_add_plugin(${name}): SOURCES is required")
  endif()
  add_library(${name} MODULE ${ARG_SOURCES})
  set_target_properties(${name} PROPERTIES
    PREFIX ""
    CXX_VISIBILITY_PRESET hidden
    VISIBILITY_INLINES_HIDDEN ON
    CXX_STANDARD 17
    CXX_STANDARD_REQUIRED ON)
  if(TARGET terramap_plugin_api)
    target_link_libraries(${name} PRIVATE terramap_plugin_api ${ARG_LIBRARIES})
    if(TARGET terramap_warnings)
      target_link_libraries(${name} PRIVATE terramap_warnings)
    endif()
    set_target_properties(${name} PROPERTIES
      LIBRARY_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/${TERRAMAP_PLUGIN_SUBDIR})
    if(NOT ARG_NO_INSTALL)
      install(TARGETS ${name} LIBRARY DESTINATION ${TERRAMAP_PLUGIN_SUBDIR})
    endif()
  else()
    target_link_libraries(${name} PRIVATE terramap::plugin_api ${ARG_LIBRARIES})
    set_target_properties(${name} PROPERTIES
      LIBRARY_OUTPUT_DIRECTORY ${CMAKE_BINARY_DIR}/plugins)
    if(NOT ARG_NO_INSTALL)
      install(TARGETS ${name} LIBRARY DESTINATION ${TERRAMAP_PLUGIN_INSTALL_DIR})
    endif()
  endif()
endfunction()
