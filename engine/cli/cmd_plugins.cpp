// `terramap plugins`: what is on the search path, and why anything was refused.
#include "command.hpp"

#include <terramap/pipeline/plugin_loader.hpp>

#include <iomanip>
#include <iostream>
#include <memory>

namespace terramap::cli {
namespace {

std::string defaultText(const ParamSpec& s) {
  if (!s.default_value) return "(required)";
  return std::visit(
      [](const auto& v) -> std::string {
        using T = std::decay_t<decltype(v)>;
        if constexpr (std::is_same_v<T, bool>) return v ? "true" : "false";
        else if constexpr (std::is_same_v<T, long>) return std::to_string(v);
        else if constexpr (std::is_same_v<T, double>) {
          std::ostringstream os;
          os << v;
          return os.str();
        } else if constexpr (std::is_same_v<T, std::string>) return "'" + v + "'";
        else {
          std::ostringstream os;
          os << "[";
          for (size_t i = 0; i < v.size(); ++i) os << (i ? ", " : "") << v[i];
          os << "]";
          return os.str();
        }
      },
      *s.default_value);
}

/// The layers with every parameter at its default (they may depend on parameters, e.g. an
/// input layer's name); a plugin with required parameters cannot be configured without them.
void printLayers(PluginHandle& h) {
  std::vector<LayerSpec> layers;
  try {
    Params p = makeParams(h.type(), h->schema());
    h->configure(p);
    layers = h->layers();
  } catch (const std::exception& e) {
    std::cout << "    layers: depend on parameters without usable defaults (" << e.what() << ")\n";
    return;
  }
  std::cout << "    layers (with default parameters):\n";
  for (const auto& l : layers) {
    std::cout << "      " << std::setw(7) << layerAccessName(l.access) << " " << std::setw(18) << l.name;
    if (l.access == LayerAccess::Create) std::cout << " [" << l.unit << "] " << l.doc;
    std::cout << "\n";
  }
}

Registrar reg{Command{"plugins", [](CLI::App& app, std::function<int()>& run) {
  auto* sub = app.add_subcommand("plugins",
      "List plugin libraries on the search path (--path, TERRAMAP_PLUGIN_PATH, then the default folder)\n"
      "and why any was refused. Exit 0 even if some were refused (they are listed).");
  auto paths = std::make_shared<std::vector<std::string>>();
  auto params = std::make_shared<bool>(false);
  sub->add_option("--path", *paths, "Extra folder to search first (repeatable)");
  sub->add_flag("--params", *params, "Also print each accepted plugin's parameters and layers");
  sub->callback([&run, paths, params] {
    run = [paths, params]() -> int {
      PluginRegistry reg(*paths);
      std::cout << "search path:\n";
      for (const auto& p : reg.searchPaths()) std::cout << "  " << p << "\n";
      const auto cands = reg.scan();
      int ok = 0, bad = 0;
      for (const auto& c : cands) (c.ok ? ok : bad) += 1;
      std::cout << "plugins (" << ok << " found, " << bad << " refused):\n";
      for (const auto& c : cands) {
        if (!c.ok) continue;
        std::cout << "  " << std::left << std::setw(16) << c.type << " " << std::setw(8) << c.version << " "
                  << c.description << "\n    " << c.path << "\n";
        // Whether `validate` can check its stages without loading it.
        try {
          const PluginFileDescription f = reg.describe(c.type);
          std::cout << "    schema: " << (f.description ? "embedded (validate checks it without loading it)"
                                                        : "none: " + f.missing + " (validate: --load-plugins)")
                    << "\n";
        } catch (const PluginError& e) {
          std::cout << "    schema: none: " << e.what() << "\n";
        }
        if (*params) {
          auto h = PluginRegistry::createFromFile(c.path, c.type);
          std::cout << "    parameters:\n";
          for (const auto& s : h->schema())
            std::cout << "      " << std::setw(26) << s.name << " " << std::setw(16) << paramTypeName(s.type) << " "
                      << std::setw(12) << defaultText(s) << " " << (s.unit.empty() ? "" : "[" + s.unit + "] ")
                      << s.doc << "\n";
          printLayers(h);
        }
      }
      if (bad) {
        std::cout << "refused:\n";
        for (const auto& c : cands)
          if (!c.ok) std::cout << "  " << c.path << "\n    " << c.reason << "\n";
      }
      return kOk;
    };
  });
}}};

}  // namespace
}  // namespace terramap::cli
