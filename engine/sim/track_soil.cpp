// Track–soil interaction: Bekker sinkage and compaction resistance, Janosi–Hanamoto traction.
#include <terramap/sim/ctl.hpp>
#include <terramap/sim/track_soil.hpp>
#include <terramap/sim/world.hpp>
#include <terramap/soil/fee.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
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

double bulldozingResistance(double c_pa, double phi_rad, double gamma_n_m3, double sinkage_m, double width_m) {
  if (!(sinkage_m > 0.0) || !(phi_rad > 0.0)) return 0.0;
  const fee::BearingFactors f = fee::bearingFactors(phi_rad);
  const double t = std::tan(phi_rad), c2 = std::cos(phi_rad) * std::cos(phi_rad);
  const double N_gamma = 2.0 * (f.N_q + 1.0) * t;
  const double K_pc = (f.N_c - t) * c2, K_pg = (2.0 * N_gamma / t + 1.0) * c2;
  return width_m * (0.667 * c_pa * sinkage_m * K_pc + 0.5 * gamma_n_m3 * sinkage_m * sinkage_m * K_pg);
}

double janosiShare(double slip, double contact_length_m, double shear_k_m) {
  const double a = std::abs(slip);
  if (a == 0.0) return 0.0;
  const double x = a * contact_length_m / shear_k_m;
  // 1 - (1 - e^-x) / x, written with expm1 so small slips keep their precision (~ x / 2).
  const double share = x < 1e-8 ? 0.5 * x : 1.0 + std::expm1(-x) / x;
  return slip > 0 ? share : -share;
}

namespace {

constexpr double kG = 9.80665;

const SoilProperties& surfaceSoilAt(const TruthTerrain& t, const SoilField& soil, double x, double y) {
  const double depth = std::max(0.0, t.initialHeightAt(x, y) - t.heightAt(x, y));
  return soil.at(x, y, std::isfinite(depth) ? depth : 0.0);
}

}  // namespace

SteadyTravel steadyTravel(const MachineSpec& m, SoilFamily family, double relative_density, double rut_pressure_factor) {
  if (!(rut_pressure_factor > 0.0)) throw std::invalid_argument("steadyTravel: rut pressure factor must be > 0");
  const soil::SoilProperties sp = soil::soilProperties(family, relative_density);
  const Terramechanics t = terramechanics(family, relative_density);
  const double W = m.mass_kg * kG, b = m.track_width_m, L = m.track_length_m;
  SteadyTravel s;
  s.pressure_pa = W / (2.0 * b * L);
  s.sinkage_m = bekkerSinkage(t, rut_pressure_factor * s.pressure_pa, b);
  s.compaction_n = 2.0 * compactionResistance(t, s.sinkage_m, b);
  s.bulldozing_n = 2.0 * bulldozingResistance(sp.fee.c_pa, sp.fee.phi_rad, sp.fee.gamma_n_m3, s.sinkage_m, b);
  s.resistance_n = m.rolling_resistance * W + s.compaction_n + s.bulldozing_n;
  s.traction_limit_n = std::min(2.0 * b * L * sp.fee.c_pa + W * std::tan(sp.fee.phi_rad), m.max_drive_force_n);
  if (!(s.resistance_n < s.traction_limit_n * janosiShare(1.0, L, t.shear_k_m))) {
    s.slip = std::numeric_limits<double>::quiet_NaN();
    return s;
  }
  double lo = 0, hi = 1;  // the share rises monotonically in slip: bisection to double precision
  for (int k = 0; k < 200 && hi - lo > 1e-16; ++k) {
    const double i = 0.5 * (lo + hi);
    (s.traction_limit_n * janosiShare(i, L, t.shear_k_m) < s.resistance_n ? lo : hi) = i;
  }
  s.slip = 0.5 * (lo + hi);
  return s;
}

void trackGround(const TruthTerrain& terrain, const SoilField& soil, const CompactTrackLoader& m, CtlLoad& load) {
  const MachineSpec& spec = m.spec();
  const double b = spec.track_width_m;
  const double p = spec.mass_kg * kG / (2.0 * b * spec.track_length_m);  // mean ground pressure
  const SoilProperties& sp = surfaceSoilAt(terrain, soil, m.x(), m.y());
  const Terramechanics tm = terramechanics(sp.family, sp.relative_density);
  load.ground_cohesion_pa = sp.fee.c_pa;
  load.ground_tan_phi = std::tan(sp.fee.phi_rad);
  load.shear_k_m = tm.shear_k_m;
  // Each track half rests on the soil under its own centre (a machine entering sand settles
  // front first). A track presses its rut where it meets unpressed soil, under its leading half
  // (the front one driving forward, the rear one reversing): that soil's compaction resistance.
  const double c = std::cos(m.yaw()), s = std::sin(m.yaw());
  const int leading = m.speed() >= 0 ? 0 : 1;
  load.compaction_n = 0;
  load.bulldozing_n = 0;
  for (int k = 0; k < 4; ++k) {
    const double lx = (k / 2 == 0 ? 0.25 : -0.25) * spec.track_length_m;
    const double ly = (k % 2 == 0 ? 0.5 : -0.5) * spec.track_gauge_m;
    const SoilProperties& q = surfaceSoilAt(terrain, soil, m.x() + c * lx - s * ly, m.y() + s * lx + c * ly);
    const Terramechanics t = terramechanics(q.family, q.relative_density);
    load.support_sinkage_m[k] = bekkerSinkage(t, p, b);
    load.support_n[k] = t.n;
    if (k / 2 == leading) {
      load.compaction_n += compactionResistance(t, load.support_sinkage_m[k], b);
      load.bulldozing_n += bulldozingResistance(q.fee.c_pa, q.fee.phi_rad, q.fee.gamma_n_m3, load.support_sinkage_m[k], b);
    }
  }
}

}  // namespace terramap::sim
