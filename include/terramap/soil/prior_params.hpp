#pragma once
/// \file
/// The soil prior a plugin takes as parameters (soil_bayes, octomap_strata): `prior_c_pa`,
/// `prior_phi_rad`, `prior_ca_pa`, `prior_delta_rad`, `prior_gamma_n_m3`, each [mean, variance]
/// in SI units (soil_parameters.hpp). Their defaults are the uniform distribution over the
/// estimator's physical ranges: mean the middle, variance span² / 12. Header-only.
#include <terramap/plugin/params.hpp>
#include <terramap/soil/soil_parameters.hpp>

#include <string>

namespace terramap::soil {

inline constexpr const char* kPriorKeys[kSoilParamCount] = {"prior_c_pa", "prior_phi_rad", "prior_ca_pa",
                                                             "prior_delta_rad", "prior_gamma_n_m3"};

/// Appends the five prior parameters to `schema`; `where` ends their documentation ("prior
/// [mean, variance] of c <where>").
inline void addPriorParams(ParamSchema& schema, const std::string& where) {
  const SoilParamVector uniform_var = uniformRangeVariances();
  for (int k = 0; k < kSoilParamCount; ++k) {
    const SoilParamInfo& info = kSoilParams[k];
    const double mid = 0.5 * (info.lo + info.hi);
    schema.push_back(param::reals(kPriorKeys[k], {mid, uniform_var[static_cast<std::size_t>(k)]}, 2, 0.0, 1e12, info.unit,
                                  std::string("prior [mean, variance] of ") + info.name + " " + where));
  }
}

/// Reads them. \throws ConfigError (Params::fail) on a variance that is not above 0.
inline void readPriorParams(const Params& p, SoilParamVector& mean, SoilParamVector& var) {
  for (int k = 0; k < kSoilParamCount; ++k) {
    const std::vector<double>& v = p.getDoubles(kPriorKeys[k]);
    if (!(v[1] > 0.0)) p.fail(kPriorKeys[k], "the prior variance must be above 0");
    mean[static_cast<std::size_t>(k)] = v[0];
    var[static_cast<std::size_t>(k)] = v[1];
  }
}

}  // namespace terramap::soil
