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
#
# The embedded schema: right after linking, terramap-plugin-schema loads the module (building
# already trusts its code), derives its parameters and its layers as a function of them, and
# objcopy writes that JSON into the module's .terramap_schema section, bound to the module's GNU
# build-id. `terramap validate` checks pipelines against it without loading the plugin
# (include/terramap/pipeline/plugin_schema.hpp). SCHEMA_PARAMS KEY=VALUE...: values the probe
# configures the plugin with where a parameter has no default or its default does not configure
# (a required model file). NO_SCHEMA: none embedded (validate then says it cannot check the
# stage without --load-plugins); for modules that must not or cannot be loaded at build time.
function(terramap_add_plugin name)
  cmake_parse_arguments(ARG "NO_INSTALL;NO_SCHEMA" "" "SOURCES;KERNEL_SOURCES;LIBRARIES;TEST_LIBRARIES;SCHEMA_PARAMS"
    ${ARGN})
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
  # The build-id is a hash of the linked module: the embedded schema names it, so a schema
  # copied into another build is not believed.
  target_link_options(${name} PRIVATE "LINKER:--build-id=sha1")
  if(NOT ARG_NO_SCHEMA)
    if(CMAKE_CROSSCOMPILING)
      message(WARNING "terramap_add_plugin(${name}): cross-compiling, so no schema is embedded (the build "
        "cannot load the module); `terramap validate` will need --load-plugins for it")
      return()
    endif()
    # The module is relinked, and so described again, when the code that describes changes (in
    # this tree its sources: the tool itself is relinked on every change of the pipeline
    # library, which would relink every plugin), so it never keeps a schema an older tool wrote.
    if(TARGET terramap_plugin_api)
      set(_tool terramap_plugin_schema)
      add_dependencies(${name} terramap_plugin_schema)
      set(_src ${CMAKE_CURRENT_FUNCTION_LIST_DIR}/..)
      set_property(TARGET ${name} APPEND PROPERTY LINK_DEPENDS ${_src}/pipeline/plugin_schema.cpp
        ${_src}/../include/terramap/pipeline/plugin_schema.hpp ${_src}/../tools/plugin_schema/main.cpp)
    else()
      set(_tool terramap::plugin_schema)
      set_property(TARGET ${name} APPEND PROPERTY LINK_DEPENDS $<TARGET_FILE:terramap::plugin_schema>)
    endif()
    set(_objcopy "${CMAKE_OBJCOPY}")
    if(NOT _objcopy)
      find_program(TERRAMAP_OBJCOPY objcopy REQUIRED)
      set(_objcopy "${TERRAMAP_OBJCOPY}")
    endif()
    set(_probe "")
    foreach(_kv IN LISTS ARG_SCHEMA_PARAMS)
      list(APPEND _probe --set "${_kv}")
    endforeach()
    add_custom_command(TARGET ${name} POST_BUILD
      COMMAND $<TARGET_FILE:${_tool}> --objcopy "${_objcopy}" ${_probe} $<TARGET_FILE:${name}>
      COMMENT "Embedding the schema of plugin ${name}"
      VERBATIM)
  endif()
endfunction()
