// `terramap eval-soil MODEL DATASET --out DIR`: the soil estimator against the simulator's truth
// (paper Fig. 11 analogue, force error, calibration, epistemic spread on the held-out set).
#ifdef TERRAMAP_SOIL_WITH_TORCH
#include "command.hpp"

#include <terramap/io/atomic_file.hpp>

#include "evaluation.hpp"

#include <terramap/io/render.hpp>

#include <cstdio>
#include <filesystem>

namespace terramap::cli {
namespace {
namespace fs = std::filesystem;

struct EvalSoilArgs {
  std::string model, dataset, out;
};

Registrar reg{Command{"eval-soil", [](CLI::App& app, std::function<int()>& run) {
  auto a = std::make_shared<EvalSoilArgs>();
  CLI::App* sub = app.add_subcommand("eval-soil",
                                     "Evaluate a soil estimator on a dataset's test and held-out splits (writes "
                                     "eval_soil.json, eval_soil.md, fig11.csv, fig11.png)");
  sub->add_option("model", a->model, "model file written by `terramap train`")->required();
  sub->add_option("dataset", a->dataset, "dataset folder written by `terramap dataset`")->required();
  sub->add_option("--out", a->out, "output folder")->required();
  sub->callback([&run, a] {
    run = [a] {
      at::set_num_threads(1);
      const pinn::SoilEstimator est = pinn::loadEstimator(a->model);
      const eval::SoilDataset ds = eval::readSoilDataset(a->dataset);
      const pinn::TrainingData data = pinn::makeTrainingData(ds, est.T(), est.P(), est.slicedGeometry());
      const pinn::SoilEvaluation ev = pinn::evaluateEstimator(est, data);
      std::error_code ec;
      fs::create_directories(a->out, ec);
      if (ec) throw OutputError(a->out + ": cannot create: " + ec.message());
      const std::string md = pinn::evaluationMarkdown(ev);
      io::writeFileAtomically(fs::path(a->out) / "eval_soil.json", pinn::evaluationJson(ev) + "\n");
      io::writeFileAtomically(fs::path(a->out) / "eval_soil.md", md);
      io::writeFileAtomically(fs::path(a->out) / "fig11.csv", pinn::fig11Csv(ev));
      io::writePng(pinn::fig11Chart(ev, "model " + fs::path(a->model).filename().string() + ", dataset " + a->dataset),
                   fs::path(a->out) / "fig11.png");
      std::printf("%s\n", md.c_str());
      for (const char* f : {"eval_soil.json", "eval_soil.md", "fig11.csv", "fig11.png"})
        std::printf("wrote %s\n", (fs::path(a->out) / f).string().c_str());
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
#endif
