#pragma once
// Terrains the simulator's sensor tests share.
#include <terramap/sim/world.hpp>

namespace terramap::sim::test {

/// Flat ground at z = 0, 40 m x 40 m centred on the origin, 2 cm nodes.
inline TruthTerrain flatTerrain40m() {
  TerrainSpec s;
  s.size_x_m = 40;
  s.size_y_m = 40;
  s.origin_x_m = -20;
  s.origin_y_m = -20;
  s.resolution_m = 0.02;
  return buildTerrain(s);
}

}  // namespace terramap::sim::test
