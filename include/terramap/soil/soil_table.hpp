#pragma once
/// \file
/// Soil families and the table that maps a family and a relative density I_d to the FEE soil
/// parameters the simulator uses as ground truth. The numbers and their sources are listed in
/// docs/sim.md ("Soil table"); every property is interpolated linearly in I_d between a loose
/// (I_d = 0) and a dense (I_d = 1) end member, which is how Vortex Studio's presets expose
/// relative density too (one scalar that moves all strength properties together).
/// Pure functions: safe from any thread.
#include <terramap/soil/fee.hpp>

#include <string>
#include <vector>

namespace terramap::soil {

enum class SoilFamily { Clay, Loam, Sand, Gravel };

/// "clay", "loam", "sand", "gravel".
const char* soilFamilyName(SoilFamily f);
/// Inverse of soilFamilyName; returns false for an unknown name.
bool parseSoilFamily(const std::string& name, SoilFamily& out);
/// All family names, for did-you-mean messages.
std::vector<std::string> soilFamilyNames();

/// Truth properties of one soil (SI units).
struct SoilProperties {
  SoilFamily family = SoilFamily::Loam;
  double relative_density = 0.5;  ///< I_d in [0, 1]
  fee::Soil fee;                  ///< c, phi, gamma (undisturbed), c_a, delta
  double swell = 1.2;             ///< loose volume / bank volume of this soil once cut (>= 1)
  double repose_rad = 0.5;        ///< angle of repose of the loose (cut) soil
};

/// The table row for (family, I_d). \throws std::invalid_argument if I_d is outside [0, 1]
/// or not finite (scenario loading checks the range first and reports file:line:col).
SoilProperties soilProperties(SoilFamily family, double relative_density);

}  // namespace terramap::soil
