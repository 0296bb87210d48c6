# Driven by CTest (so CI's `make test` runs it: the short sanitizer pass, next to the ASan host):
# builds the engine and the threading tests with ThreadSanitizer in a scratch build tree (Debug:
# compiles fast) and runs the tests of the threading contracts: the engine's (engine.hpp:
# push()/editMap() on one thread, snapshot() on any, snapshots read while the engine writes;
# runPipeline's source running ahead on its own thread),
# the executor's (every index once, slots, exceptions, a tile kernel bit for bit) and the
# simulator's (physics overlapping the scans, stopped while it runs ahead). Executor and the
# simulator run their tasks on std::threads in TSan builds (parallel.hpp), so every
# synchronisation is visible to TSan. Any data race stops the run with TSan's report.
# Inputs: -DSOURCE_DIR= -DWORK_DIR= -DJOBS=   (`make test-tsan` runs every test the same way)
set(build ${WORK_DIR}/tsan-build)
execute_process(COMMAND ${CMAKE_COMMAND} -S ${SOURCE_DIR} -B ${build} -G Ninja
  -DCMAKE_BUILD_TYPE=Debug -DTERRAMAP_SANITIZE=thread -DTERRAMAP_BUILD_TESTS=ON
  -DTERRAMAP_BUILD_BENCHMARKS=OFF -DTERRAMAP_WITH_PYTHON=OFF -DTERRAMAP_WITH_WEB=OFF -DTERRAMAP_WITH_TORCH=OFF
  -DTERRAMAP_TEST_SANITIZED_HOST=OFF
  RESULT_VARIABLE rc OUTPUT_QUIET)
if(rc)
  message(FATAL_ERROR "configuring the ThreadSanitizer build failed: ${rc}")
endif()
execute_process(COMMAND ${CMAKE_COMMAND} --build ${build} -j ${JOBS} --target test_tsan_contracts
  RESULT_VARIABLE rc OUTPUT_VARIABLE log)
if(rc)
  message(FATAL_ERROR "building the ThreadSanitizer tests failed: ${rc}\n${log}")
endif()
# One program (tests/CMakeLists.txt: test_tsan_contracts) holds the three files of the contracts.
set(program test_tsan_contracts)
set(ENV{TSAN_OPTIONS} "halt_on_error=1:second_deadlock_stack=1:suppressions=${SOURCE_DIR}/scripts/tsan.supp")
foreach(filter
    "Engine.EditMapAndPushOnOneThreadSnapshotsOnAnother:Engine.SnapshotIsConsistentWhileTheEngineKeepsWriting:Run.TheSourceRunsAheadOnItsOwnThreadAndItsProgressAndErrorsArriveInStep"
    "Executor.*:LayeredMap.TileKernelIsBitIdenticalAtOneAndTwoThreads"
    "Simulator.SameSeedIsBitIdenticalForAnyThreadCount:Simulator.StopsCleanlyWhileThePhysicsRunsAhead")
  execute_process(COMMAND ${build}/bin/${program} --gtest_filter=${filter}
    RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  message("${out}")
  # "[  PASSED  ] 0 tests" would pass a filter that matched nothing: every filter must run tests.
  if(rc OR err MATCHES "ThreadSanitizer" OR NOT out MATCHES "PASSED" OR out MATCHES "PASSED  \\] 0 tests")
    message(FATAL_ERROR "${program} ${filter} failed under ThreadSanitizer (${rc}):\n${out}\n${err}")
  endif()
  message("ThreadSanitizer: ${program} ${filter}: no race")
endforeach()
