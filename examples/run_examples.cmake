# Driven by CTest: install terramap to a scratch prefix, build examples/ against it as a user
# would, validate a pipeline that uses the example plugin with the installed `terramap`, and run
# the embedding program (it checks its own results and exits non-zero otherwise).
# Inputs: -DBUILD_DIR= -DSOURCE_DIR= -DWORK_DIR=
include(${SOURCE_DIR}/tests/cmake/scratch_package.cmake)
file(REMOVE_RECURSE ${WORK_DIR})
set(prefix ${WORK_DIR}/prefix)
terramap_scratch_install(${BUILD_DIR} ${prefix})
terramap_build_against(${prefix} ${SOURCE_DIR}/examples ${WORK_DIR}/build "-Wall -Wextra -Werror" "the examples")

execute_process(COMMAND ${WORK_DIR}/build/embed_app RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}")
if(rc OR NOT out MATCHES "embed_app: ok")
  message(FATAL_ERROR "the embedding example failed (${rc}):\n${out}${err}")
endif()

# The plugin's own map-dependent checks (its configure()) reach `terramap validate
# --load-plugins`, with the key's position. Without the switch validate runs no plugin code: it
# checks the stage against the schema the example's build embedded, and says what it left out.
file(WRITE ${WORK_DIR}/bad.yaml "version: 1
map: {resolution: 0.1, size: [20, 20], layers: [elevation]}
plugin_paths: [build/plugins]
pipeline:
  - {name: r, type: roughness, params: {window_m: 0.05, run_on: [tock]}}
")
execute_process(COMMAND ${prefix}/bin/terramap validate ${WORK_DIR}/bad.yaml --allow-config-plugin-paths
  RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
if(NOT rc EQUAL 0 OR NOT out MATCHES "cross-parameter and map checks \\(their configure\\(\\)\\) were not run"
   OR out MATCHES "not checked:")
  message(FATAL_ERROR "terramap validate should check the example from its embedded schema and name what it "
    "did not run (${rc}):\n${out}")
endif()
execute_process(COMMAND ${prefix}/bin/terramap validate ${WORK_DIR}/bad.yaml --allow-config-plugin-paths
  --load-plugins RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE out)
if(NOT rc EQUAL 8 OR NOT out MATCHES "bad.yaml:5:[0-9]+: pipeline\\[0\\].params.window_m: must be at least the map's resolution"
   OR NOT out MATCHES "pipeline\\[0\\].params.run_on: unknown event kind 'tock'")
  message(FATAL_ERROR "terramap validate should report both problems of the roughness stage (${rc}):\n${out}")
endif()
execute_process(COMMAND ${prefix}/bin/terramap plugins --params --path ${WORK_DIR}/build/plugins
  OUTPUT_VARIABLE out RESULT_VARIABLE rc)
if(rc OR NOT out MATCHES "roughness +\\[m\\] standard deviation of elevation")
  message(FATAL_ERROR "terramap plugins --params should show the example's layer and its doc:\n${out}")
endif()
message("examples built against the installed package and ran")
