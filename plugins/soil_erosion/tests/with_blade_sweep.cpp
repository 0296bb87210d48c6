// Compiles blade_sweep's blade_sweep.cpp into this test program so that the chain test can run the
// real blade plugin before erosion (the test target builds only soil_erosion's own sources).
#include "../../blade_sweep/blade_sweep.cpp"
