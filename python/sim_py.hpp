#pragma once
// The `sim` submodule of terramap's extension (sim_py.cpp): Env and VectorEnv.
#include <pybind11/pybind11.h>

void bindSim(pybind11::module_& parent);
