// `terramap fee`: evaluate the fundamental equation of earthmoving once and print JSON.
#include "command.hpp"

#include <terramap/soil/fee.hpp>

#include <nlohmann/json.hpp>

#include <cmath>
#include <iostream>
#include <memory>
#include <sstream>
#include <utility>
#include <string>

namespace terramap::cli {
namespace {

constexpr double kDegToRad = 3.14159265358979323846 / 180.0;

struct FeeOptions {
  double c_pa = 0, phi_deg = 0, gamma_n_m3 = 0, ca_pa = 0, delta_deg = 0;
  double alpha_deg = 0, rho_deg = 0, d_m = 0, w_m = 0, q_n = 0;
  double beta_deg = std::nan("");
  std::string beta_mode = "min";
};

/// The offending values, in the units the user typed, so the reason can be acted on.
std::string detail(fee::Validity v, const FeeOptions& o, double betaRad) {
  using fee::Validity;
  const double betaDeg = betaRad / kDegToRad;
  std::ostringstream m;
  m.precision(10);
  switch (v) {
    case Validity::DepthNotPositive: m << "--d-m " << o.d_m; break;
    case Validity::WidthNotPositive: m << "--w-m " << o.w_m; break;
    case Validity::NegativeCohesion: m << "--c-pa " << o.c_pa; break;
    case Validity::NegativeAdhesion: m << "--ca-pa " << o.ca_pa; break;
    case Validity::NegativeUnitWeight: m << "--gamma-n-m3 " << o.gamma_n_m3; break;
    case Validity::NegativeSurcharge: m << "--q-n " << o.q_n; break;
    case Validity::PhiOutOfRange: m << "--phi-deg " << o.phi_deg; break;
    case Validity::DeltaOutOfRange: m << "--delta-deg " << o.delta_deg; break;
    case Validity::AlphaOutOfRange: m << "--alpha-deg " << o.alpha_deg; break;
    case Validity::RhoOutOfRange: m << "--rho-deg " << o.rho_deg; break;
    case Validity::BetaOutOfRange: m << "beta = " << betaDeg << " deg"; break;
    case Validity::RhoPlusBetaTooLarge: m << "rho + beta = " << o.rho_deg + betaDeg << " deg"; break;
    case Validity::EtaOutOfRange:
      m << "eta = " << o.delta_deg + o.rho_deg + o.phi_deg + betaDeg << " deg";
      break;
    case Validity::AlphaPhiBetaOutOfRange:
      m << "alpha + phi + beta = " << o.alpha_deg + o.phi_deg + betaDeg << " deg";
      break;
    case Validity::NotFinite: {
      const std::pair<const char*, double> all[] = {
          {"--c-pa", o.c_pa},     {"--phi-deg", o.phi_deg},     {"--gamma-n-m3", o.gamma_n_m3},
          {"--ca-pa", o.ca_pa},   {"--delta-deg", o.delta_deg}, {"--alpha-deg", o.alpha_deg},
          {"--rho-deg", o.rho_deg}, {"--d-m", o.d_m},           {"--w-m", o.w_m},
          {"--q-n", o.q_n},       {"beta", betaDeg}};
      m << "not finite:";
      for (const auto& [name, value] : all)
        if (!std::isfinite(value)) m << " " << name;
      break;
    }
    case Validity::NoAdmissibleBeta:
      m << "N_gamma has no admissible minimum for these angles; try --beta nominal or --beta-deg";
      break;
    case Validity::Valid: break;
  }
  return m.str();
}

int runFee(const FeeOptions& o, bool betaGiven) {
  fee::Soil s;
  s.c_pa = o.c_pa;
  s.phi_rad = o.phi_deg * kDegToRad;
  s.gamma_n_m3 = o.gamma_n_m3;
  s.ca_pa = o.ca_pa;
  s.delta_rad = o.delta_deg * kDegToRad;
  fee::Geometry g;
  g.alpha_rad = o.alpha_deg * kDegToRad;
  g.rho_rad = o.rho_deg * kDegToRad;
  g.d_m = o.d_m;
  g.w_m = o.w_m;
  g.q_n = o.q_n;

  fee::Result r;
  if (betaGiven) {
    r = fee::evaluate(s, g, o.beta_deg * kDegToRad);
  } else if (o.beta_mode == "nominal") {
    r = fee::evaluateAtBetaNominal(s, g);
  } else {
    r = fee::evaluateAtBetaMin(s, g);
  }

  // ordered_json keeps the documented key order; NaN (e.g. no beta*) prints as null.
  nlohmann::ordered_json j;
  j["beta_rad"] = r.beta_rad;
  j["eta_rad"] = r.n.eta_rad;
  j["N_gamma"] = r.n.N_gamma;
  j["N_c"] = r.n.N_c;
  j["N_Q"] = r.n.N_Q;
  j["N_ca"] = r.n.N_ca;
  j["f_N"] = r.f_N;
  j["Fx_N"] = r.F_N.x();
  j["Fz_N"] = r.F_N.y();
  j["Fx_total_N"] = r.F_total_N.x();
  j["Fz_total_N"] = r.F_total_N.y();
  j["valid"] = r.valid();
  j["reason"] = r.valid() ? std::string()
                          : std::string(fee::validityName(r.validity)) + ": rule '" +
                                fee::validityRule(r.validity) + "' does not hold (" +
                                detail(r.validity, o, r.beta_rad) + ")";
  std::cout << j.dump(2) << "\n";
  return r.valid() ? kOk : kInvalid;
}

void setupFee(CLI::App& app, std::function<int()>& run) {
  auto o = std::make_shared<FeeOptions>();
  CLI::App* sub = app.add_subcommand(
      "fee", "Evaluate the fundamental equation of earthmoving (FEE) for one soil and blade; print JSON.");
  sub->footer(
      "Prints one JSON object (ALGORITHMS.md §E): beta_rad, eta_rad, N_gamma, N_c, N_Q, N_ca (dimensionless),\n"
      "f_N (resultant magnitude), Fx_N, Fz_N (the paper's F), Fx_total_N, Fz_total_N (F plus adhesion along\n"
      "the blade face, what the simulator uses), valid, reason. Angles are given in degrees and reported in\n"
      "radians; forces are in N.\n"
      "Convention: x horizontal along the direction of travel, z up; the force is that of the blade on the\n"
      "soil. rho and beta are measured from the soil surface (which rises at alpha ahead of the blade); d is\n"
      "the edge depth normal to the surface. Values that cannot be computed print as null.\n"
      "Exit code: 0 when the FEE is valid, 8 when a validity rule fails (the JSON is still printed and\n"
      "'reason' names the rule and the offending value), 2 on a bad command line.\n"
      "Example (Coulomb passive pressure, K_p = 6.105):\n"
      "  terramap fee --c-pa 0 --phi-deg 30 --gamma-n-m3 18000 --ca-pa 0 --delta-deg 20 --alpha-deg 0 \\\n"
      "               --rho-deg 90 --d-m 1 --w-m 1 --q-n 0 --beta min");
  sub->add_option("--c-pa", o->c_pa, "cohesion c [Pa], >= 0")->required();
  sub->add_option("--phi-deg", o->phi_deg, "internal friction angle phi [deg], 0 <= phi < 90")->required();
  sub->add_option("--gamma-n-m3", o->gamma_n_m3, "soil unit weight gamma [N/m^3], >= 0")->required();
  sub->add_option("--ca-pa", o->ca_pa, "soil-tool adhesion c_a [Pa], >= 0")->required();
  sub->add_option("--delta-deg", o->delta_deg, "soil-tool friction angle delta [deg], 0 <= delta < 90")
      ->required();
  sub->add_option("--alpha-deg", o->alpha_deg,
                  "surface slope alpha [deg], |alpha| < 90, positive = terrain rises ahead of the blade")
      ->required();
  sub->add_option("--rho-deg", o->rho_deg,
                  "rake angle rho [deg] between blade and soil surface, through the soil; 0 < rho < 180")
      ->required();
  sub->add_option("--d-m", o->d_m, "cutting depth d [m] normal to the surface, > 0")->required();
  sub->add_option("--w-m", o->w_m, "blade width in contact w [m], > 0")->required();
  sub->add_option("--q-n", o->q_n, "surcharge weight Q [N] of loose soil in front of the blade, >= 0")
      ->required();
  CLI::Option* betaDeg =
      sub->add_option("--beta-deg", o->beta_deg, "failure-plane angle beta [deg] to use as given, 0 < beta < 90");
  CLI::Option* betaMode =
      sub->add_option("--beta", o->beta_mode,
                      "how to choose beta when --beta-deg is absent: 'min' = beta* minimising N_gamma\n"
                      "(closed form), 'nominal' = Rankine pi/4 - phi/2")
          ->check(CLI::IsMember({"min", "nominal"}))
          ->capture_default_str();
  betaDeg->excludes(betaMode);
  betaMode->excludes(betaDeg);
  sub->callback([&run, o, betaDeg] {
    const bool betaGiven = betaDeg->count() > 0;
    run = [o, betaGiven] { return runFee(*o, betaGiven); };
  });
}

const Registrar kRegisterFee{Command{"fee", setupFee}};

}  // namespace
}  // namespace terramap::cli
