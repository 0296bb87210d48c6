# Driven by CTest: builds the host (libraries, CLI, bundled plugins) with AddressSanitizer in
# a scratch build tree, installs it, and runs the out-of-tree plugins built with -march=native
# against it (run_out_of_tree.cmake). The installed package carries -fsanitize=address to the
# plugins, so host and plugin agree; any allocation freed by the other side's allocator, or
# any out-of-bounds access in the boundary code, stops the run with ASan's report.
# Inputs: -DSOURCE_DIR= -DWORK_DIR= -DJOBS= -DCXX_FLAGS=
set(build ${WORK_DIR}/host-build)
set(prefix ${WORK_DIR}/host-prefix)
# Debug (-O0): compiles in a fraction of the optimised time; the run is only 1 simulated second.
# Of the bundled plugins only the two the pipeline of run_out_of_tree.cmake loads.
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${build} -G Ninja
  -DCMAKE_BUILD_TYPE=Debug -DTERRAMAP_SANITIZE=address -DTERRAMAP_BUILD_TESTS=OFF
  -DTERRAMAP_BUILD_BENCHMARKS=OFF -DTERRAMAP_WITH_PYTHON=OFF -DTERRAMAP_WITH_WEB=OFF -DTERRAMAP_WITH_TORCH=OFF
  "-DTERRAMAP_PLUGINS=lidar_fusion;smooth_filter" -DCMAKE_INSTALL_PREFIX=${prefix}
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(rc)
  message(FATAL_ERROR "configuring the AddressSanitizer host failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${build} -j ${JOBS} RESULT_VARIABLE rc OUTPUT_VARIABLE log)
if(rc)
  message(FATAL_ERROR "building the AddressSanitizer host failed: ${rc}\n${log}")
endif()
file(REMOVE_RECURSE ${prefix})
execute_process(COMMAND ${CMAKE_COMMAND} --install ${build} RESULT_VARIABLE rc OUTPUT_QUIET)
if(rc)
  message(FATAL_ERROR "installing the AddressSanitizer host failed: ${rc}")
endif()
set(ENV{ASAN_OPTIONS} "detect_leaks=1:abort_on_error=0:halt_on_error=1")
execute_process(COMMAND ${CMAKE_COMMAND} -DSOURCE_DIR=${SOURCE_DIR} -DWORK_DIR=${WORK_DIR}/plugins
  -DPREFIX=${prefix} "-DCXX_FLAGS=${CXX_FLAGS}" -P ${SOURCE_DIR}/tests/out_of_tree/run_out_of_tree.cmake
  RESULT_VARIABLE rc)
if(rc)
  message(FATAL_ERROR "the out-of-tree plugins failed against the AddressSanitizer host")
endif()
message("AddressSanitizer host ran the out-of-tree plugins built with '${CXX_FLAGS}'")
