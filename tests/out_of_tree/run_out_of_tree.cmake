# Driven by CTest: build the out-of-tree plugins against an installed terramap and run them
# through the *installed* terramap, once with the default flags and once with CXX_FLAGS (e.g.
# -march=native); the plugin that reads events must see the same values in both builds.
# Inputs: -DSOURCE_DIR= -DWORK_DIR= and either -DBUILD_DIR= (installed here to a scratch
# prefix) or -DPREFIX= (already installed); optional -DCXX_FLAGS= and -DREQUIRE_CPU_FLAG=
# (skipped, printing "SKIP:", when /proc/cpuinfo does not list it).
if(REQUIRE_CPU_FLAG)
  file(READ /proc/cpuinfo cpuinfo)
  if(NOT cpuinfo MATCHES "flags[^\n]* ${REQUIRE_CPU_FLAG}[ \n]")
    message("SKIP: this CPU has no ${REQUIRE_CPU_FLAG}")
    return()
  endif()
endif()
include(${CMAKE_CURRENT_LIST_DIR}/../cmake/scratch_package.cmake)
file(REMOVE_RECURSE ${WORK_DIR})
if(NOT PREFIX)
  set(PREFIX ${WORK_DIR}/prefix)
  terramap_scratch_install(${BUILD_DIR} ${PREFIX})
endif()

# Builds the out-of-tree project with `flags` into ${WORK_DIR}/<tag>, runs the installed
# terramap on it and returns the pose_probe record of report.json in `out_record`.
function(build_and_run tag flags out_record)
  set(dir ${WORK_DIR}/${tag})
  terramap_build_against(${PREFIX} ${SOURCE_DIR}/tests/out_of_tree ${dir}/build "${flags}"
    "[${tag}] the out-of-tree plugins")
  # A short simulator run: Pose, BladePose and Observation events (Isometry3d members) reach
  # the probe; the installed lidar_fusion maps the terrain the simulated LiDAR sees, and the
  # slope plugin reads that elevation and writes the slope as whole layers (toMatrix/fromMatrix)
  # and checks both against the host's per-cell access (its record, asserted below).
  file(WRITE ${dir}/pipeline.yaml "version: 1
map: {resolution: 0.5, size: [20, 20], center: [4, 0]}
threads: 2
plugin_paths: [build/plugins]
source: {type: sim, scenario: ${PREFIX}/share/terramap/configs/scenarios/dense_strip.yaml, max_time_s: 1.0}
pipeline:
  - {name: probe, type: pose_probe}
  - {name: lidar, type: lidar_fusion}
  - {name: slope, type: slope_layer, params: {output_layer: slope}}
  - {name: smooth, type: smooth_filter, params: {input_layer: slope, output_layer: slope_smooth, run_on: []}}
outputs: {dir: out, geotiff: [slope], png: [], snapshot: false}
")
  execute_process(COMMAND ${PREFIX}/bin/terramap plugins --path ${dir}/build/plugins
    OUTPUT_VARIABLE out RESULT_VARIABLE rc)
  if(rc OR NOT out MATCHES "slope_layer" OR NOT out MATCHES "pose_probe" OR NOT out MATCHES "smooth_filter")
    message(FATAL_ERROR "[${tag}] installed terramap does not list the out-of-tree and installed plugins:\n${out}")
  endif()
  # Their build embedded their schemas with the installed terramap-plugin-schema: validate checks
  # their stages without loading them (a bad value is caught, nothing is left unchecked).
  execute_process(COMMAND ${PREFIX}/bin/terramap validate ${dir}/pipeline.yaml --allow-config-plugin-paths
    --set slope.output_layr=slope
    RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(NOT rc EQUAL 8 OR err MATCHES "not checked" OR NOT err MATCHES "did you mean 'output_layer'")
    message(FATAL_ERROR "[${tag}] validate did not check the out-of-tree plugins from their embedded schemas "
      "(${rc}):\n${out}${err}")
  endif()
  execute_process(COMMAND ${PREFIX}/bin/terramap validate ${dir}/pipeline.yaml --allow-config-plugin-paths
    RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  if(rc OR err MATCHES "not checked")
    message(FATAL_ERROR "[${tag}] validate did not find the out-of-tree plugins' schemas (${rc}):\n${out}${err}")
  endif()
  execute_process(COMMAND ${PREFIX}/bin/terramap run ${dir}/pipeline.yaml --quiet --allow-config-plugin-paths
    RESULT_VARIABLE rc ERROR_VARIABLE err)
  # LeakSanitizer's own tracer thread can crash while it stops the process's threads for the
  # leak check at exit ("Tracer caught signal 11", google/sanitizers#1353: intermittent, seen here
  # once under a full parallel `make test`). That is the checker failing, not a leak nor the run:
  # run once more. A leak ("detected memory leaks") or any other failure still fails at once.
  if(rc AND err MATCHES "Tracer caught signal" AND err MATCHES "LeakSanitizer has encountered a fatal error"
     AND NOT err MATCHES "detected memory leaks")
    message("[${tag}] LeakSanitizer's tracer crashed at exit (not a leak); running once more:\n${err}")
    file(REMOVE_RECURSE ${dir}/out)
    execute_process(COMMAND ${PREFIX}/bin/terramap run ${dir}/pipeline.yaml --quiet --allow-config-plugin-paths
      RESULT_VARIABLE rc ERROR_VARIABLE err)
  endif()
  if(rc)
    message(FATAL_ERROR "[${tag}] installed terramap could not run the out-of-tree plugins (${rc}): ${err}")
  endif()
  if(NOT EXISTS ${dir}/out/map.tif OR NOT EXISTS ${dir}/out/report.json)
    message(FATAL_ERROR "[${tag}] no outputs from the run")
  endif()
  file(READ ${dir}/out/report.json report)
  string(JSON stages LENGTH "${report}" stages)
  math(EXPR last "${stages} - 1")
  set(record "")
  set(slope_record "")
  foreach(i RANGE ${last})
    string(JSON name GET "${report}" stages ${i} name)
    string(JSON type GET "${report}" stages ${i} type)
    if(name STREQUAL "slope" AND NOT type STREQUAL "slope_layer")
      message(FATAL_ERROR "[${tag}] report does not show the out-of-tree stage")
    endif()
    if(name STREQUAL "probe")
      string(JSON record GET "${report}" stages ${i} records 0)
    endif()
    if(name STREQUAL "slope")
      string(JSON slope_record GET "${report}" stages ${i} records 0)
    endif()
  endforeach()
  if(record STREQUAL "")
    message(FATAL_ERROR "[${tag}] no pose_probe record in the report")
  endif()
  # The slope plugin's layers: the elevation it read through its matrix helper and the slope it
  # wrote are the host's cells bit for bit, every slope is the central-difference slope of the
  # host's heights (to 1e-5 rad of float rounding), and there is terrain to see: at least 40 of
  # the 400 cells have a slope (the LiDAR maps ~10 m around the machine in 1 s; 0.5 m cells),
  # and some of it is not flat (> 1 mrad).
  if(slope_record STREQUAL "")
    message(FATAL_ERROR "[${tag}] no slope_layer record in the report")
  endif()
  foreach(key cells finite nonzero read_mismatch write_mismatch slope_off)
    string(JSON slope_${key} GET "${slope_record}" ${key})
  endforeach()
  if(NOT slope_cells EQUAL 400 OR slope_finite LESS 40 OR slope_nonzero LESS 20 OR NOT slope_read_mismatch EQUAL 0
     OR NOT slope_write_mismatch EQUAL 0 OR NOT slope_slope_off EQUAL 0)
    message(FATAL_ERROR "[${tag}] the slope plugin's layers disagree with the host's cells: ${slope_record}")
  endif()
  message("[${tag}] slope: ${slope_record}")
  string(JSON poses GET "${record}" poses)
  string(JSON unexpected GET "${record}" unexpected)
  string(JSON frames_wrong GET "${record}" frames_wrong)
  string(JSON rot_err GET "${record}" max_rotation_error)
  if(poses LESS 100 OR NOT unexpected EQUAL 0 OR NOT frames_wrong EQUAL 0 OR NOT rot_err LESS 1e-9)
    message(FATAL_ERROR "[${tag}] the plugin misread the host's events: ${record}")
  endif()
  message("[${tag}] flags '${flags}': ${record}")
  # What must not depend on the plugin's flags: the events read and which slope cells are known
  # (the slope values themselves may differ in the last bit where -march=native fuses a multiply-add).
  set(${out_record} "${record} slope cells known: ${slope_finite}" PARENT_SCOPE)
endfunction()

build_and_run(default "" reference)
if(CXX_FLAGS)
  build_and_run(flagged "${CXX_FLAGS}" flagged)
  if(NOT flagged STREQUAL reference)
    message(FATAL_ERROR "a plugin built with '${CXX_FLAGS}' read other event values than one built "
      "with the default flags:\n  default: ${reference}\n  flagged: ${flagged}")
  endif()
endif()
message("out-of-tree plugins built against the installed package and ran")
