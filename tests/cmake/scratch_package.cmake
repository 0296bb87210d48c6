# Helpers for CTest scripts that build programs against an *installed* terramap, as users do.

# Installs the build tree `build_dir` into `prefix`.
function(terramap_scratch_install build_dir prefix)
  execute_process(COMMAND ${CMAKE_COMMAND} --install ${build_dir} --prefix ${prefix} RESULT_VARIABLE rc OUTPUT_QUIET)
  if(rc)
    message(FATAL_ERROR "installing ${build_dir} into ${prefix} failed: ${rc}")
  endif()
endfunction()

# Configures and builds the CMake project in `source` into `build` against the package in
# `prefix` (Release, Ninja), with CMAKE_CXX_FLAGS = `cxx_flags`; `what` names it in errors.
function(terramap_build_against prefix source build cxx_flags what)
  execute_process(COMMAND ${CMAKE_COMMAND} -S ${source} -B ${build} -G Ninja
    -DCMAKE_BUILD_TYPE=Release -DCMAKE_PREFIX_PATH=${prefix} "-DCMAKE_CXX_FLAGS=${cxx_flags}"
    RESULT_VARIABLE rc OUTPUT_QUIET)
  if(rc)
    message(FATAL_ERROR "configuring ${what} against the installed package failed: ${rc}")
  endif()
  execute_process(COMMAND ${CMAKE_COMMAND} --build ${build} RESULT_VARIABLE rc OUTPUT_VARIABLE log)
  if(rc)
    message(FATAL_ERROR "building ${what} failed: ${rc}\n${log}")
  endif()
endfunction()
