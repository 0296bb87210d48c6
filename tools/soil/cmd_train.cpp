// `terramap train CONFIG`: trains the soil estimator's ensemble (plugins/soil_pinn/trainer.hpp).
#ifdef TERRAMAP_SOIL_WITH_TORCH
#include "command.hpp"

#include <terramap/core/error.hpp>
#include <terramap/soil/pinn_sample.hpp>

#include "trainer.hpp"
#include "yaml/reader.hpp"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace terramap::cli {
namespace {
namespace fs = std::filesystem;

std::string resolve(const std::string& base, const std::string& p) {
  if (p.empty() || fs::path(p).is_absolute()) return p;
  return (fs::path(base) / p).lexically_normal().string();
}

pinn::TrainConfig loadTrainConfig(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw ConfigError(path + ": cannot open the training configuration");
  std::ostringstream os;
  os << in.rdbuf();
  const std::string base = fs::path(path).has_parent_path() ? fs::path(path).parent_path().string() : ".";
  yaml::Diagnostics d;
  d.file = path;
  const YAML::Node root = yaml::load(os.str(), path);
  yaml::MapReader r(d, root, "");
  pinn::TrainConfig c;
  r.integer("version", 1, 1, 1);
  c.dataset = resolve(base, r.strRequired("dataset"));
  c.out = resolve(base, r.strRequired("out"));
  c.checkpoint_dir = resolve(base, r.str("checkpoint_dir", ""));
  if (r.has("history")) {
    yaml::MapReader h = r.child("history");
    c.T = h.integer("T", c.T, 1, 600);
    c.P = h.integer("P", c.P, 1, 600);
    if (c.P > c.T) h.error(h.node("P"), "P", "must not exceed T (the horizon is the end of the history)");
    h.finish();
  }
  if (r.has("hidden")) {
    const std::vector<double> v = r.vec("hidden", {}, 0);
    c.hidden.clear();
    for (double x : v) {
      if (x < 1 || x > 4096 || x != std::floor(x)) r.error(r.node("hidden"), "hidden", "layer widths must be integers in [1, 4096]");
      c.hidden.push_back(static_cast<int>(x));
    }
  }
  c.members = r.integer("members", c.members, 1, 64);
  c.seed = static_cast<std::int64_t>(r.unsignedInt("seed", 1));
  c.batch = r.integer("batch", c.batch, 1, 100000);
  c.max_epochs = r.integer("max_epochs", c.max_epochs, 1, 100000);
  c.patience = r.integer("patience", c.patience, 1, 100000);
  c.learning_rate = r.num("learning_rate", c.learning_rate, 1e-8, 1.0);
  if (r.has("beta_base")) {
    const std::string b = r.str("beta_base", "min");
    try {
      c.beta_base = pinn::parseBetaBase(b);
    } catch (const std::invalid_argument&) {
      r.error(r.node("beta_base"), "beta_base", "must be 'min' (beta* minimising N_gamma) or 'nominal' (pi/4 - phi/2), got '" + b + "'");
    }
  }
  c.mask_stalled = r.boolean("mask_stalled", c.mask_stalled);
  c.edge_thickness_m = r.num("edge_thickness_m", c.edge_thickness_m, 0.0, 0.5);
  if (r.has("gate_feature")) {
    const std::string g = r.str("gate_feature", "");
    const std::vector<std::string>& names = soil::obsFeatureNames();
    const auto it = std::find(names.begin(), names.end(), g);
    if (g == "none")
      c.gate_feature = -1;
    else if (it == names.end())
      r.error(r.node("gate_feature"), "gate_feature", "must name an observation feature (e.g. blade_vz_map_mps) or be none, got '" + g + "'");
    else if (!(c.edge_thickness_m > 0))
      r.error(r.node("gate_feature"), "gate_feature", "needs edge_thickness_m > 0 (the gate belongs to the penetration term)");
    else
      c.gate_feature = static_cast<int>(it - names.begin());
  }
  c.q_gamma_ref_n_m3 = r.num("surcharge_gamma_ref_n_m3", c.q_gamma_ref_n_m3, 0.0, 1e5);
  if (r.has("gate")) {
    const std::string g = r.str("gate", "learned");
    if (g != "learned" && g != "observed")
      r.error(r.node("gate"), "gate", "must be 'learned' (a sigmoid head) or 'observed' (the sign of gate_feature), got '" + g + "'");
    else if (g == "observed" && c.gate_feature < 0)
      r.error(r.node("gate"), "gate", "'observed' needs gate_feature (the observation whose sign says the edge descends)");
    c.gate_observed = g == "observed";
  }
  if (r.has("geometry")) {
    const std::string g = r.str("geometry", "mean");
    if (g != "mean" && g != "sliced")
      r.error(r.node("geometry"), "geometry",
              "must be 'mean' (the sweep's mean depth and cutting width) or 'sliced' (the one wedge holding the cut's "
              "cross-section), got '" + g + "'");
    c.sliced_geometry = g == "sliced";
  }
  if (r.has("loss")) {
    yaml::MapReader l = r.child("loss");
    pinn::LossWeights& w = c.weights;
    w.lambda_F = l.num("lambda_F", w.lambda_F, 0, 1e6);
    w.lambda_NLL = l.num("lambda_NLL", w.lambda_NLL, 0, 1e6);
    w.lambda_beta = l.num("lambda_beta", w.lambda_beta, 0, 1e6);
    w.lambda_range = l.num("lambda_range", w.lambda_range, 0, 1e6);
    w.lambda_res = l.num("lambda_res", w.lambda_res, 0, 1e6);
    w.lambda_Fr = l.num("lambda_Fr", w.lambda_Fr, 0, 1e6);
    w.lambda_prior = l.num("lambda_prior", w.lambda_prior, 0, 1e6);
    w.lambda_soil = l.num("lambda_soil", w.lambda_soil, 0, 1e6);
    const std::vector<double> wxz = l.vec("w_xz", {w.w_xz[0], w.w_xz[1]}, 2);  // [x, z] weights of the force terms
    if (wxz.size() == 2) w.w_xz = {wxz[0], wxz[1]};
    l.finish();
  }
  r.finish();
  d.throwIfAny();
  return c;
}

struct TrainArgs {
  std::string config, dataset, out;
  int members = 0, max_epochs = 0;
  bool quiet = false;
};

Registrar reg{Command{"train", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<TrainArgs>();
  CLI::App* sub = app.add_subcommand(
      "train", "Train the soil estimator's ensemble from a dataset (configs/train/pinn.yaml); resumes from its checkpoints");
  sub->add_option("config", a->config, "training configuration YAML")->required();
  sub->add_option("--dataset", a->dataset, "override the dataset folder");
  sub->add_option("--out", a->out, "override the model file");
  sub->add_option("--members", a->members, "override the ensemble size");
  sub->add_option("--max-epochs", a->max_epochs, "override the epoch limit");
  sub->add_flag("--quiet,-q", a->quiet, "no progress");
  sub->callback([&run, a] {
    run = [a] {
      pinn::TrainConfig cfg = loadTrainConfig(a->config);
      if (!a->dataset.empty()) cfg.dataset = a->dataset;
      if (!a->out.empty()) cfg.out = a->out;
      if (a->members > 0) cfg.members = a->members;
      if (a->max_epochs > 0) cfg.max_epochs = a->max_epochs;
      const bool tty = !a->quiet && isatty(fileno(stderr));
      const pinn::TrainReport rep = pinn::trainEnsemble(cfg, [&](int m, int epoch, double tr, double va, double fmae) {
        if (a->quiet) return;
        std::fprintf(stderr, tty ? "\r  member %d/%d  epoch %3d/%d  train %.4f  validation %.4f (force wMAE %.0f N)   "
                                 : "member %d/%d epoch %d/%d train %.4f validation %.4f (force wMAE %.0f N)\n",
                     m + 1, cfg.members, epoch, cfg.max_epochs, tr, va, fmae);
        std::fflush(stderr);
      });
      if (tty) std::fprintf(stderr, "\n");
      std::printf("trained %zu members on %ld samples (validation %ld) in %.1f s\n", rep.members.size(),
                  rep.train_samples, rep.validation_samples, rep.wall_s);
      for (std::size_t m = 0; m < rep.members.size(); ++m)
        std::printf("  member %zu: %d epochs, best validation loss %.4f at epoch %d%s\n", m, rep.members[m].epochs,
                    rep.members[m].best_validation_loss, rep.members[m].best_epoch, rep.members[m].resumed ? " (resumed)" : "");
      std::printf("wrote %s\n", cfg.out.c_str());
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
#endif
