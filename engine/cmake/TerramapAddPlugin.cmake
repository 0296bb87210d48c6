# terramap_add_plugin(<name> SOURCES <src>... [KERNEL_SOURCES <src>...] [LIBRARIES <lib>...]
#                     [TEST_LIBRARIES <lib>...] [NO_INSTALL])
#
# Builds a terramap plugin: a shared library named <name> (no "lib" prefix) with hidden
# visibility, linked to terramap::plugin_api, placed where the host looks for plugins
# (<libdir>/terramap/plugins in the build tree and in the install tree).
# The same function serves in-tree plugins and out-of-tree ones (find_package(terramap)).
#
# KERNEL_SOURCES (everything but the export, i.e. the TERRAMAP_PLUGIN line) build a static,
# position-independent library <name>_kernels that the module links. A MODULE cannot be linked,
# so tests and benchmarks link <name>_kernels to use the plugin's classes directly instead of
# compiling (or #include-ing) its .cpp files. It carries the plugin's include directory and
# LIBRARIES, is built with the module's flags (so results are the same bits) and is not
# installed. TEST_LIBRARIES: what the plugin's own tests (plugins/<name>/tests) link besides
# <name>_kernels, e.g. another plugin's kernels for a chain test; kept as the target property
# TERRAMAP_TEST_LIBRARIES for tests/CMakeLists.txt, as LIBRARIES is in TERRAMAP_PLUGIN_LIBRARIES.
function(terramap_add_plugin name)
  cmake_parse_arguments(ARG "NO_INSTALL" "" "SOURCES;KERNEL_SOURCES;LIBRARIES;TEST_LIBRARIES" ${ARGN})
  if(NOT ARG_SOURCES)
    message(FATAL_ERROR "terramap_add_plugin(${name}): SOURCES is required")
  endif()
  if(TARGET terramap_plugin_api)
    set(_api terramap_plugin_api)
  else()
    set(_api terramap::plugin_api)
  endif()
  add_library(${name} MODULE ${ARG_SOURCES})
  if(ARG_KERNEL_SOURCES)
    add_library(${name}_kernels STATIC ${ARG_KERNEL_SOURCES})
    set_target_properties(${name}_kernels PROPERTIES
      POSITION_INDEPENDENT_CODE ON
      CXX_VISIBILITY_PRESET hidden
      VISIBILITY_INLINES_HIDDEN ON
      CXX_STANDARD 17
      CXX_STANDARD_REQUIRED ON)
    target_include_directories(${name}_kernels PUBLIC ${CMAKE_CURRENT_SOURCE_DIR})
    target_link_libraries(${name}_kernels PUBLIC ${_api} ${ARG_LIBRARIES})
    if(TARGET terramap_warnings)
      target_link_libraries(${name}_kernels PRIVATE terramap_warnings)
    endif()
    target_link_libraries(${name} PRIVATE ${name}_kernels)
  endif()
  set_target_properties(${name} PROPERTIES
    TERRAMAP_PLUGIN_LIBRARIES "${ARG_LIBRARIES}"
    TERRAMAP_TEST_LIBRARIES "${ARG_TEST_LIBRARIES}")
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
