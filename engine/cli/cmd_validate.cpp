// `terramap validate PIPELINE.yaml`: every error at once, non-zero exit if any.
#include "command.hpp"

#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/source.hpp>

#include <algorithm>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

namespace terramap::cli {
namespace {

Registrar reg{Command{"validate", [](CLI::App& app, std::function<int()>& run) {
  auto* sub = app.add_subcommand("validate",
      "Check a pipeline YAML without running it: structure, plugin types and libraries, parameters\n"
      "(types, ranges, unknown keys with did-you-mean), layer flow, source settings.\n"
      "No plugin code runs: parameters and layers are checked against the schema embedded in each\n"
      "plugin file; what that cannot check is printed as a warning (--load-plugins checks it).\n"
      "Prints every problem, one per line as file:line:col: key.path: message. Exit 0 if valid, 8 if not.");
  auto file = std::make_shared<std::string>();
  auto set = std::make_shared<std::vector<std::string>>();
  auto load = std::make_shared<bool>(false);
  sub->add_option("pipeline", *file, "Pipeline YAML file")->required();
  sub->add_option("--set", *set, "Stage parameter as `run --set` would apply it, STAGE.KEY=VALUE (repeatable)");
  sub->add_flag("--load-plugins", *load,
                "Load and configure each stage's plugin (runs its code), to run its own cross-parameter and map "
                "checks too and to check plugins without an embedded schema; for plugins you trust");
  sub->callback([&run, file, set, load] {
    run = [file, set, load]() -> int {
      std::vector<std::string> errors;
      PipelineSpec spec;
      try {
        spec = parsePipelineFile(*file);
        applyParamOverrides(spec, *set);
      } catch (const ConfigError& e) {
        std::cerr << e.what() << "\n";
        std::cerr << *file << ": invalid (structure errors above; fix them to check plugins and layers)\n";
        return kInvalid;
      }
      // Refused plugin_paths are one problem among the others: the stages are still checked
      // against the folders the user trusts.
      std::vector<std::string> config_paths = spec.plugin_paths;
      try {
        (void)PluginRegistry::forPipeline(config_paths, spec.plugin_paths_where);
      } catch (const ConfigError& e) {
        errors.push_back(e.what());
        config_paths.clear();
      }
      const PluginRegistry registry(config_paths);
      std::vector<std::string> unchecked;
      const auto stage_errors = *load ? Engine::validate(spec, registry)
                                      : Engine::validateWithoutLoading(spec, registry, unchecked);
      errors.insert(errors.end(), stage_errors.begin(), stage_errors.end());
      for (const auto& u : unchecked) std::cerr << "warning: " << u << "\n";
      try {
        (void)makeSource(spec);
      } catch (const Error& e) {
        errors.push_back(e.what());
      }
      for (const auto& e : errors) std::cerr << e << "\n";
      if (!errors.empty()) {
        std::cerr << *file << ": invalid (" << errors.size() << " problem" << (errors.size() == 1 ? "" : "s") << ")\n";
        return kInvalid;
      }
      // Stages the embedded schemas could not check are not called valid without a word.
      const auto not_checked = std::count_if(unchecked.begin(), unchecked.end(), [](const std::string& u) {
        return u.find(": parameters and layers not checked: ") != std::string::npos ||
               u.find(": layers not checked: ") != std::string::npos;
      });
      std::cout << *file << ": valid (" << spec.stages.size() << " stages, source '" << spec.source.type << "'"
                << (not_checked ? "; " + std::to_string(not_checked) + " not checked, see the warnings" : "") << ")\n";
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
