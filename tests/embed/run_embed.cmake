# Driven by CTest: install the build tree to a scratch prefix, build tests/embed against it
# (linking only terramap::pipeline), run it, and check that neither the simulator library nor
# HDF5 is on its link line or among its direct dependencies, and that the simulator library is
# not loaded at all. (GDAL, which terramap::io uses for GeoTIFF, may itself load an HDF5
# driver library; that is GDAL's dependency, not the engine's, so only the direct ones count.)
# Inputs: -DBUILD_DIR= -DSOURCE_DIR= -DWORK_DIR=
include(${CMAKE_CURRENT_LIST_DIR}/../cmake/scratch_package.cmake)
file(REMOVE_RECURSE ${WORK_DIR})
set(prefix ${WORK_DIR}/prefix)
terramap_scratch_install(${BUILD_DIR} ${prefix})
terramap_build_against(${prefix} ${SOURCE_DIR}/tests/embed ${WORK_DIR}/build "" "the embedding program")

# The embedding snippet of docs/embedding.md and every public header were compiled with it (-Werror).
if(NOT EXISTS ${WORK_DIR}/build/readme_snippet)
  message(FATAL_ERROR "docs/embedding.md's snippet was not compiled (no '## C++' cpp block?)")
endif()

# The link line, as Ninja runs it.
execute_process(COMMAND ninja -C ${WORK_DIR}/build -t commands embed OUTPUT_VARIABLE commands RESULT_VARIABLE rc)
string(REGEX MATCH "[^\n]*-o embed[^\n]*" link_line "${commands}")
if(rc OR link_line STREQUAL "")
  message(FATAL_ERROR "no link command for the embedding program:\n${commands}")
endif()
message("link line: ${link_line}")
foreach(bad terramap_sim terramap_eval hdf5)
  if(link_line MATCHES "${bad}")
    message(FATAL_ERROR "the embedding program's link line names ${bad}:\n${link_line}")
  endif()
endforeach()

execute_process(COMMAND readelf -d ${WORK_DIR}/build/embed OUTPUT_VARIABLE dyn RESULT_VARIABLE rc)
string(REGEX MATCHALL "\\(NEEDED\\)[^\n]*" needed "${dyn}")
message("direct dependencies: ${needed}")
if(rc OR NOT needed MATCHES "libterramap_pipeline")
  message(FATAL_ERROR "readelf found no libterramap_pipeline among the program's dependencies:\n${dyn}")
endif()
if(needed MATCHES "terramap_sim|terramap_eval|hdf5")
  message(FATAL_ERROR "the embedding program depends directly on the simulator or HDF5: ${needed}")
endif()
execute_process(COMMAND ldd ${WORK_DIR}/build/embed OUTPUT_VARIABLE closure RESULT_VARIABLE rc)
if(rc OR closure MATCHES "libterramap_sim|libterramap_eval")
  message(FATAL_ERROR "the simulator is loaded with the embedding program:\n${closure}")
endif()

execute_process(COMMAND ${WORK_DIR}/build/embed RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
message("${out}")
if(rc OR NOT out MATCHES "cells=192 mean=2.000000")
  message(FATAL_ERROR "the embedding program did not run the pipeline (${rc}):\n${out}${err}")
endif()
if(NOT out MATCHES "sim source: [^\n]*unknown source type 'sim'[^\n]*registerSimSource")
  message(FATAL_ERROR "a pipeline-only embedder should be told where the sim source lives:\n${out}")
endif()
message("an embedder linking terramap::pipeline links neither the simulator nor HDF5")

# The installed Python package (when built) imports from the prefix alone: its RPATH finds the
# installed libraries and the plugins, with no build tree on any path.
file(GLOB py_pkg ${prefix}/lib/python3*/dist-packages/terramap)
if(py_pkg)
  get_filename_component(py_site ${py_pkg} DIRECTORY)
  execute_process(COMMAND ${CMAKE_COMMAND} -E env PYTHONPATH=${py_site} TERRAMAP_PLUGIN_PATH= /usr/bin/python3
    ${SOURCE_DIR}/tests/embed/installed_python.py
    RESULT_VARIABLE rc OUTPUT_VARIABLE out ERROR_VARIABLE err)
  message("${out}")
  if(rc OR NOT out MATCHES "installed python: ${py_site}/terramap/__init__.py 1.0")
    message(FATAL_ERROR "the installed Python package does not work from the prefix (${rc}):\n${out}${err}")
  endif()
endif()
