# Driven by CTest: install the build tree to a scratch prefix, build the out-of-tree plugin
# against it, and run the *installed* terramap with a pipeline that uses that plugin.
# Inputs: -DBUILD_DIR= -DSOURCE_DIR= -DWORK_DIR=
file(REMOVE_RECURSE ${WORK_DIR})
set(prefix ${WORK_DIR}/prefix)
execute_process(COMMAND ${CMAKE_COMMAND} --install ${BUILD_DIR} --prefix ${prefix}
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(rc)
  message(FATAL_ERROR "install failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR}/tests/out_of_tree -B ${WORK_DIR}/build -G Ninja
  -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=${prefix} RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "configuring the out-of-tree plugin against the installed package failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${WORK_DIR}/build RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "building the out-of-tree plugin failed: ${rc}")
endif()
file(WRITE ${WORK_DIR}/pipeline.yaml "version: 1
map: {resolution: 0.5, size: [20, 20], layers: [{name: elevation, unit: m, fill: 1.0}]}
threads: 1
plugin_paths: [build/plugins]
source: {type: none}
pipeline:
  - {name: slope, type: slope_layer, params: {output_layer: slope}}
  - {name: smooth, type: smooth_filter, params: {input_layer: slope, output_layer: slope_smooth, run_on: []}}
outputs: {dir: out, geotiff: [slope], png: [], snapshot: false}
")
execute_process(COMMAND ${prefix}/bin/terramap plugins --path ${WORK_DIR}/build/plugins
  OUTPUT_VARIABLE out RESULT_VARIABLE rc)
message("${out}")
if(rc OR NOT out MATCHES "slope_layer" OR NOT out MATCHES "smooth_filter")
  message(FATAL_ERROR "installed terramap does not list the out-of-tree and installed plugins")
endif()
execute_process(COMMAND ${prefix}/bin/terramap run ${WORK_DIR}/pipeline.yaml --quiet
  RESULT_VARIABLE rc ERROR_VARIABLE err)
if(rc)
  message(FATAL_ERROR "installed terramap could not run the out-of-tree plugin (${rc}): ${err}")
endif()
if(NOT EXISTS ${WORK_DIR}/out/map.tif OR NOT EXISTS ${WORK_DIR}/out/report.json)
  message(FATAL_ERROR "no outputs from the run")
endif()
file(READ ${WORK_DIR}/out/report.json report)
if(NOT report MATCHES "\"type\": \"slope_layer\"")
  message(FATAL_ERROR "report does not show the out-of-tree stage")
endif()
message("out-of-tree plugin built against the installed package and ran")
