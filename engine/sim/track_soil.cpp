// Track–soil interaction: Bekker sinkage and compaction resistance, Janosi–Hanamoto traction.
#include <terramap/sim/track_soil.hpp>

#include <cmath>
#include <stdexcept>

namespace terramap::sim {
namespace {

using soil::SoilFamily;

// End members {loose (I_d = 0), dense (I_d = 1)} (docs/sim.md "Track–soil interaction").
// Measured rows of Wong's terrain-value table (also in Project Chrono's SCM examples): dry sand
// (Land Locomotion Lab; K 2.5 cm loose), LETE sand (K 1.2 cm), sandy loam (LLL, 15 % moisture),
// clayey soil (Thailand, 38 %). Where a dense member has no measured row (loam, clay, gravel's
// both ends) it is a model choice: the loose row's moduli x 3, K x 2/3 (stiffer and shearing
// up sooner with density, as the strength properties of the soil table do).
struct Row { Terramechanics loose, dense; };

Row rowOf(SoilFamily f) {
  switch (f) {
    case SoilFamily::Sand:
      return {{1.1, 0.99e3, 1528.43e3, 0.025}, {0.793, 102e3, 5301e3, 0.012}};
    case SoilFamily::Gravel:
      return {{0.793, 102e3, 5301e3, 0.012}, {0.793, 306e3, 15903e3, 0.008}};
    case SoilFamily::Loam:
      return {{0.7, 5.27e3, 1515.04e3, 0.025}, {0.7, 15.81e3, 4545.12e3, 0.0167}};
    case SoilFamily::Clay:
    default:
      return {{0.5, 13.19e3, 692.15e3, 0.025}, {0.5, 39.57e3, 2076.45e3, 0.0167}};
  }
}

double logLerp(double a, double b, double s) { return std::exp((1 - s) * std::log(a) + s * std::log(b)); }

}  // namespace

Terramechanics terramechanics(SoilFamily family, double relative_density) {
  if (!(relative_density >= 0.0 && relative_density <= 1.0))
    throw std::invalid_argument("terramechanics: relative density outside [0, 1]");
  const Row r = rowOf(family);
  const double s = relative_density;
  Terramechanics t;
  t.n = (1 - s) * r.loose.n + s * r.dense.n;
  t.k_c = logLerp(r.loose.k_c, r.dense.k_c, s);
  t.k_phi = logLerp(r.loose.k_phi, r.dense.k_phi, s);
  t.shear_k_m = logLerp(r.loose.shear_k_m, r.dense.shear_k_m, s);
  return t;
}

double bekkerSinkage(const Terramechanics& t, double pressure_pa, double width_m) {
  if (!(pressure_pa > 0.0)) return 0.0;
  return std::pow(pressure_pa / (t.k_c / width_m + t.k_phi), 1.0 / t.n);
}

double compactionResistance(const Terramechanics& t, double sinkage_m, double width_m) {
  if (!(sinkage_m > 0.0)) return 0.0;
  return width_m * (t.k_c / width_m + t.k_phi) * std::pow(sinkage_m, t.n + 1.0) / (t.n + 1.0);
}

double janosiShare(double slip, double contact_length_m, double shear_k_m) {
  const double a = std::abs(slip);
  if (a == 0.0) return 0.0;
  const double x = a * contact_length_m / shear_k_m;
  // 1 - (1 - e^-x) / x, written with expm1 so small slips keep their precision (~ x / 2).
  const double share = x < 1e-8 ? 0.5 * x : 1.0 + std::expm1(-x) / x;
  return slip > 0 ? share : -share;
}

}  // namespace terramap::sim
