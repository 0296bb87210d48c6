# Driven by CTest: where does `cmake --install` put an out-of-tree plugin?
#  1. with `--prefix P`: under P/<plugin dir> and nowhere else (not in terramap's prefix, not in
#     the system's /usr/lib/terramap/plugins);
#  2. with no prefix chosen: in terramap's own prefix, where the installed host finds it without
#     any search path (checked with the installed `terramap plugins`).
# Inputs: -DBUILD_DIR= (terramap's build tree) -DSOURCE_DIR= -DWORK_DIR= -DPLUGIN_SUBDIR=
include(${CMAKE_CURRENT_LIST_DIR}/../cmake/scratch_package.cmake)
file(REMOVE_RECURSE ${WORK_DIR})
set(PREFIX ${WORK_DIR}/terramap_prefix)
terramap_scratch_install(${BUILD_DIR} ${PREFIX})
terramap_build_against(${PREFIX} ${SOURCE_DIR}/tests/out_of_tree ${WORK_DIR}/build "" "the out-of-tree plugins")

set(plugin_prefix ${WORK_DIR}/plugin_prefix)
execute_process(COMMAND ${CMAKE_COMMAND} --install ${WORK_DIR}/build --prefix ${plugin_prefix}
  RESULT_VARIABLE rc OUTPUT_VARIABLE log ERROR_VARIABLE log)
if(rc)
  message(FATAL_ERROR "cmake --install --prefix ${plugin_prefix} failed (${rc}):\n${log}")
endif()
if(NOT EXISTS ${plugin_prefix}/${PLUGIN_SUBDIR}/slope_layer.so)
  message(FATAL_ERROR "--prefix ${plugin_prefix} did not put slope_layer.so into "
    "${plugin_prefix}/${PLUGIN_SUBDIR}; the install said:\n${log}")
endif()
# Every file the install wrote must be under the prefix it was given.
string(REGEX MATCHALL "(Installing|Up-to-date): [^\n]*" lines "${log}")
foreach(line IN LISTS lines)
  string(REGEX REPLACE "^[^:]*: " "" path "${line}")
  string(FIND "${path}" "${plugin_prefix}/" at)
  if(NOT at EQUAL 0)
    message(FATAL_ERROR "cmake --install --prefix ${plugin_prefix} wrote outside it: ${path}")
  endif()
endforeach()
if(EXISTS ${PREFIX}/${PLUGIN_SUBDIR}/slope_layer.so)
  message(FATAL_ERROR "--prefix ${plugin_prefix} also wrote into terramap's prefix ${PREFIX}")
endif()

# No prefix chosen: next to the host.
execute_process(COMMAND ${CMAKE_COMMAND} --install ${WORK_DIR}/build
  RESULT_VARIABLE rc OUTPUT_VARIABLE log ERROR_VARIABLE log)
if(rc OR NOT EXISTS ${PREFIX}/${PLUGIN_SUBDIR}/slope_layer.so)
  message(FATAL_ERROR "without --prefix the plugin should land in terramap's prefix "
    "${PREFIX}/${PLUGIN_SUBDIR} (rc ${rc}):\n${log}")
endif()
execute_process(COMMAND ${PREFIX}/bin/terramap plugins OUTPUT_VARIABLE out RESULT_VARIABLE rc)
if(rc OR NOT out MATCHES "slope_layer")
  message(FATAL_ERROR "the installed terramap does not find the plugin installed next to it:\n${out}")
endif()
message("plugin installed to ${plugin_prefix}/${PLUGIN_SUBDIR} with --prefix and to ${PREFIX}/${PLUGIN_SUBDIR} without")
