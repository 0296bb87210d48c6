// Soil table: family + relative density -> truth FEE parameters. Sources in docs/sim.md.
#include <terramap/soil/soil_table.hpp>

#include <cmath>
#include <stdexcept>

namespace terramap::soil {
namespace {

constexpr double kDeg = M_PI / 180.0;

/// Loose (I_d = 0) and dense (I_d = 1) end members of one family.
struct Row {
  SoilFamily family;
  const char* name;
  double phi_deg[2];     // internal friction angle
  double c_kpa[2];       // cohesion
  double gamma_kn[2];    // bank (undisturbed) unit weight, kN/m^3
  double delta_ratio;    // delta / phi (soil-steel friction)
  double ca_ratio;       // c_a / c (adhesion factor)
  double swell[2];       // bank -> loose volume ratio
  double repose_deg;     // angle of repose of the loose soil
};

// See docs/sim.md "Soil table" for the source of every column.
constexpr Row kRows[] = {
    {SoilFamily::Clay, "clay", {17.0, 27.0}, {10.0, 70.0}, {15.0, 20.0}, 0.45, 0.60, {1.20, 1.40}, 30.0},
    {SoilFamily::Loam, "loam", {26.0, 36.0}, {4.0, 25.0}, {14.0, 19.0}, 0.55, 0.50, {1.12, 1.30}, 32.0},
    {SoilFamily::Sand, "sand", {28.0, 43.0}, {0.0, 0.0}, {15.0, 19.5}, 0.67, 0.00, {1.05, 1.15}, 33.0},
    {SoilFamily::Gravel, "gravel", {33.0, 46.0}, {0.0, 0.0}, {16.0, 21.0}, 0.60, 0.00, {1.05, 1.17}, 36.0},
};

const Row& row(SoilFamily f) {
  for (const Row& r : kRows)
    if (r.family == f) return r;
  throw std::invalid_argument("unknown soil family");
}

double lerp(const double (&v)[2], double t) { return v[0] + (v[1] - v[0]) * t; }

}  // namespace

const char* soilFamilyName(SoilFamily f) { return row(f).name; }

bool parseSoilFamily(const std::string& name, SoilFamily& out) {
  for (const Row& r : kRows) {
    if (name == r.name) {
      out = r.family;
      return true;
    }
  }
  return false;
}

std::vector<std::string> soilFamilyNames() {
  std::vector<std::string> n;
  for (const Row& r : kRows) n.emplace_back(r.name);
  return n;
}

SoilProperties soilProperties(SoilFamily family, double relative_density) {
  if (!std::isfinite(relative_density) || relative_density < 0.0 || relative_density > 1.0)
    throw std::invalid_argument("relative density must be in [0, 1]");
  const Row& r = row(family);
  const double t = relative_density;
  SoilProperties p;
  p.family = family;
  p.relative_density = t;
  p.fee.phi_rad = lerp(r.phi_deg, t) * kDeg;
  p.fee.c_pa = lerp(r.c_kpa, t) * 1e3;
  p.fee.gamma_n_m3 = lerp(r.gamma_kn, t) * 1e3;
  p.fee.delta_rad = r.delta_ratio * p.fee.phi_rad;
  p.fee.ca_pa = r.ca_ratio * p.fee.c_pa;
  p.swell = lerp(r.swell, t);
  p.repose_rad = r.repose_deg * kDeg;
  return p;
}

}  // namespace terramap::soil
