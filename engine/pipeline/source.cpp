#include <terramap/pipeline/source.hpp>
#include <terramap/core/text.hpp>

#include <mutex>

namespace terramap {

Source::~Source() = default;

void registerModuleSources();  // source_builtin.cpp

namespace {
std::map<std::string, SourceFactory>& factories() {
  static std::map<std::string, SourceFactory> f;
  return f;
}
std::mutex& factoriesMutex() {
  static std::mutex m;
  return m;
}

class NoneSource : public Source {
 public:
  bool next(Event&) override { return false; }
  double progress() const override { return 1.0; }
};

void registerBuiltins();
}  // namespace

void registerSource(const std::string& type, SourceFactory factory) {
  std::lock_guard<std::mutex> lock(factoriesMutex());
  factories()[type] = std::move(factory);
}

std::vector<std::string> sourceTypes() {
  registerBuiltins();
  std::lock_guard<std::mutex> lock(factoriesMutex());
  std::vector<std::string> out;
  for (const auto& [k, v] : factories()) out.push_back(k);
  return out;
}

std::unique_ptr<Source> makeSource(const PipelineSpec& spec) {
  registerBuiltins();
  SourceFactory f;
  {
    std::lock_guard<std::mutex> lock(factoriesMutex());
    auto it = factories().find(spec.source.type);
    if (it != factories().end()) f = it->second;
  }
  if (!f) {
    const auto types = sourceTypes();
    throw ConfigError((spec.source.where.empty() ? spec.file : spec.source.where) + ".type: unknown source type '" +
                      spec.source.type + "'" + didYouMean(spec.source.type, types) + "; known: [" +
                      joinStrings(types) + "]" +
                      (spec.source.type == "sim"
                           ? " (the simulator source is registered by terramap::sim::registerSimSource() in "
                             "terramap::eval, which the terramap CLI calls)"
                           : ""));
  }
  return f(spec);
}

void checkSourceKeys(const SourceSpec& s, const std::vector<std::string>& known) {
  std::string errors;
  for (const auto& [k, r] : s.settings) {
    bool ok = false;
    for (const auto& n : known) ok = ok || n == k;
    if (!ok)
      errors += (errors.empty() ? "" : "\n") + r.where + ": unknown key for source type '" + s.type + "'" +
                didYouMean(k, known) + "; known keys: type, " + joinStrings(known);
  }
  if (!errors.empty()) throw ConfigError(errors);
}

std::string sourceString(const SourceSpec& s, const std::string& key, bool required, const std::string& def) {
  auto it = s.settings.find(key);
  if (it == s.settings.end()) {
    if (required) throw ConfigError(s.where + ": source." + key + " is required for source type '" + s.type + "'");
    return def;
  }
  if (auto p = std::get_if<std::string>(&it->second.value)) return *p;
  throw ConfigError(it->second.where + ": must be a string");
}

double sourceDouble(const SourceSpec& s, const std::string& key, bool required, double def) {
  auto it = s.settings.find(key);
  if (it == s.settings.end()) {
    if (required) throw ConfigError(s.where + ": source." + key + " is required for source type '" + s.type + "'");
    return def;
  }
  if (auto p = std::get_if<double>(&it->second.value)) return *p;
  if (auto p = std::get_if<long>(&it->second.value)) return static_cast<double>(*p);
  throw ConfigError(it->second.where + ": must be a number");
}

namespace {
void registerBuiltins() {
  static std::once_flag once;
  std::call_once(once, [] {
    registerSource("none", [](const PipelineSpec& spec) -> std::unique_ptr<Source> {
      checkSourceKeys(spec.source, {});
      return std::make_unique<NoneSource>();
    });
    registerModuleSources();
  });
}
}  // namespace

}  // namespace terramap
