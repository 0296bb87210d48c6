#pragma once
/// \file
/// The five soil parameters the estimator infers, one table for everyone who carries them as a
/// vector: the network's output columns (soil_pinn), SoilEstimateRecord, the soil layers
/// (soil_bayes, read by fee_index and the truth report) and the simulator's soil truth. Order
/// [c, φ, c_a, δ, γ]; fee::Soil orders its fields differently ([c, φ, γ, c_a, δ]), so code that
/// converts goes through toFee()/fromFee().
///
/// Units SI: c and c_a in Pa, φ and δ in rad, γ in N/m³. [lo, hi] is the physical range the
/// estimator squashes its output into (wide enough for the simulator's four soil families,
/// loose sand to dense clay). Header-only constants: no state, safe from any thread.
#include <terramap/soil/fee.hpp>

#include <array>

namespace terramap::soil {

enum SoilParam : int { kParamC = 0, kParamPhi, kParamCa, kParamDelta, kParamGamma, kSoilParamCount };

struct SoilParamInfo {
  const char* name;   ///< short name ("c", "phi", ...)
  const char* layer;  ///< the map layer holding its posterior mean (its variance: layer + "_var")
  const char* unit;   ///< SI unit of the value
  double lo, hi;      ///< physical range
};

inline constexpr double kDegree = 3.14159265358979323846 / 180.0;
inline constexpr SoilParamInfo kSoilParams[kSoilParamCount] = {
    {"c", "soil_c", "Pa", 0.0, 60e3},
    {"phi", "soil_phi", "rad", 10 * kDegree, 50 * kDegree},
    {"ca", "soil_ca", "Pa", 0.0, 30e3},
    {"delta", "soil_delta", "rad", 5 * kDegree, 40 * kDegree},
    {"gamma", "soil_gamma", "N/m^3", 12e3, 22e3},
};

/// How a person reads each parameter (tables, charts, printed reports): the factor from its SI
/// value and the unit shown. Angles in degrees; the layers and JSON keep SI (radians).
struct SoilParamDisplay {
  double scale;
  const char* unit;
};
inline constexpr SoilParamDisplay kSoilDisplay[kSoilParamCount] = {
    {1e-3, "kPa"}, {1 / kDegree, "deg"}, {1e-3, "kPa"}, {1 / kDegree, "deg"}, {1e-3, "kN/m^3"}};

using SoilParamVector = std::array<double, kSoilParamCount>;

/// The variance of the uniform distribution over each parameter's physical range, span² / 12:
/// what "no knowledge beyond the range" means as a variance. One value for everyone who uses
/// it: the estimator's ambiguity variance (paper Eq. 7) and its input-distance term, and the
/// default prior of the soil layers and the strata (prior_params.hpp).
inline SoilParamVector uniformRangeVariances() {
  SoilParamVector v{};
  for (int k = 0; k < kSoilParamCount; ++k) {
    const double span = kSoilParams[k].hi - kSoilParams[k].lo;
    v[static_cast<std::size_t>(k)] = span * span / 12.0;
  }
  return v;
}

/// [c, φ, c_a, δ, γ] -> fee::Soil.
inline fee::Soil toFee(const SoilParamVector& v) {
  return {v[kParamC], v[kParamPhi], v[kParamGamma], v[kParamCa], v[kParamDelta]};
}
/// fee::Soil -> [c, φ, c_a, δ, γ].
inline SoilParamVector fromFee(const fee::Soil& s) { return {s.c_pa, s.phi_rad, s.ca_pa, s.delta_rad, s.gamma_n_m3}; }

}  // namespace terramap::soil
