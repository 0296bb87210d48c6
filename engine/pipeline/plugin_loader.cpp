#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/core/text.hpp>

#define BOOST_DLL_USE_STD_FS
#include <boost/dll/runtime_symbol_info.hpp>
#include <boost/dll/shared_library.hpp>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>

namespace terramap {

namespace fs = std::filesystem;

class PluginLibrary {
 public:
  boost::dll::shared_library lib;
  std::string path, type, version, description;
  Plugin* (*create)() = nullptr;
  void (*destroy)(Plugin*) = nullptr;
};

namespace {

std::string hex32(std::uint32_t v) {
  std::ostringstream os;
  os << v;
  return os.str();
}

/// Loads and checks one library. Throws PluginError with the file and the mismatch.
std::shared_ptr<PluginLibrary> openLibrary(const std::string& path) {
  // Accepted libraries stay loaded for the life of the process: objects they made (records
  // on the bus, exceptions in flight, snapshots a user holds) may outlive every plugin
  // instance, and running their destructors after an unload would crash.
  static std::mutex mu;
  static auto* cache = new std::map<std::string, std::shared_ptr<PluginLibrary>>();  // never destroyed
  const std::string key = fs::weakly_canonical(path).string();
  std::lock_guard<std::mutex> lock(mu);
  if (auto it = cache->find(key); it != cache->end()) return it->second;

  auto lib = std::make_shared<PluginLibrary>();
  lib->path = path;
  try {
    lib->lib.load(boost::dll::fs::path(path),
                  boost::dll::load_mode::rtld_now | boost::dll::load_mode::rtld_local);
  } catch (const std::exception& e) {
    throw PluginError(path + ": cannot load plugin library: " + e.what());
  }
  if (!lib->lib.has(kPluginInfoSymbol))
    throw PluginError(path + ": missing symbol '" + std::string(kPluginInfoSymbol) +
                      "': not a terramap plugin (export it with TERRAMAP_PLUGIN)");
  const auto& info = lib->lib.get<const terramap_plugin_info_t>(kPluginInfoSymbol);
  // abi_version and info_size are read first: they are at the same place in every version.
  if (info.abi_version != TERRAMAP_PLUGIN_ABI_VERSION)
    throw PluginError(path + ": plugin ABI version mismatch: expected " + hex32(TERRAMAP_PLUGIN_ABI_VERSION) +
                      ", found " + hex32(info.abi_version) + " (rebuild the plugin against this terramap)");
  if (info.info_size != sizeof(terramap_plugin_info_t))
    throw PluginError(path + ": plugin info record size mismatch: expected " +
                      std::to_string(sizeof(terramap_plugin_info_t)) + " bytes, found " +
                      std::to_string(info.info_size) + " (rebuild the plugin against this terramap)");
  const char* fp = info.fingerprint ? info.fingerprint : "(null)";
  if (std::strcmp(fp, TERRAMAP_BUILD_FINGERPRINT) != 0)
    throw PluginError(path + ": plugin build fingerprint mismatch: expected '" +
                      std::string(TERRAMAP_BUILD_FINGERPRINT) + "', found '" + fp +
                      "' (rebuild the plugin with the same compiler and terramap version)");
  for (const char* sym : {kPluginCreateSymbol, kPluginDestroySymbol})
    if (!lib->lib.has(sym))
      throw PluginError(path + ": missing symbol '" + std::string(sym) + "' (export it with TERRAMAP_PLUGIN)");
  lib->type = info.name ? info.name : "";
  lib->version = info.version ? info.version : "";
  lib->description = info.description ? info.description : "";
  if (lib->type.empty()) throw PluginError(path + ": plugin info record has an empty name");
  lib->create = &lib->lib.get<Plugin*()>(kPluginCreateSymbol);
  lib->destroy = &lib->lib.get<void(Plugin*)>(kPluginDestroySymbol);
  (*cache)[key] = lib;
  return lib;
}

PluginHandle instantiate(const std::shared_ptr<PluginLibrary>& lib) {
  Plugin* p = nullptr;
  try {
    p = lib->create();
  } catch (const std::exception& e) {
    throw PluginError(lib->path + ": plugin '" + lib->type + "' threw while being created: " + e.what());
  }
  if (!p) throw PluginError(lib->path + ": plugin '" + lib->type + "' create() returned null");
  return PluginHandle(lib, p);
}

}  // namespace

PluginHandle::PluginHandle(std::shared_ptr<PluginLibrary> lib, Plugin* p) : lib_(std::move(lib)), plugin_(p) {}
PluginHandle::PluginHandle(PluginHandle&& o) noexcept : lib_(std::move(o.lib_)), plugin_(o.plugin_) {
  o.plugin_ = nullptr;
}
PluginHandle& PluginHandle::operator=(PluginHandle&& o) noexcept {
  if (this != &o) {
    reset();
    lib_ = std::move(o.lib_);
    plugin_ = o.plugin_;
    o.plugin_ = nullptr;
  }
  return *this;
}
PluginHandle::~PluginHandle() { reset(); }
void PluginHandle::reset() {
  if (plugin_ && lib_) lib_->destroy(plugin_);  // deleted by the library that allocated it
  plugin_ = nullptr;
  lib_.reset();  // only now may the library unload
}
const std::string& PluginHandle::type() const { return lib_->type; }
const std::string& PluginHandle::path() const { return lib_->path; }
const std::string& PluginHandle::version() const { return lib_->version; }

PluginRegistry::PluginRegistry(std::vector<std::string> extra_paths) : paths_(std::move(extra_paths)) {
  if (const char* env = std::getenv("TERRAMAP_PLUGIN_PATH")) {
    std::stringstream ss(env);
    std::string item;
    while (std::getline(ss, item, ':'))
      if (!item.empty()) paths_.push_back(item);
  }
  paths_.push_back(defaultPluginDir());
}

std::string PluginRegistry::defaultPluginDir() {
  const boost::dll::fs::path self = boost::dll::this_line_location();
  return (fs::path(self.parent_path().string()) / "terramap" / "plugins").lexically_normal().string();
}

std::string PluginRegistry::find(const std::string& type) const {
  for (const auto& dir : paths_) {
    const fs::path p = fs::path(dir) / (type + ".so");
    std::error_code ec;
    if (fs::is_regular_file(p, ec)) return p.string();
  }
  return {};
}

std::vector<PluginCandidate> PluginRegistry::scan() const {
  std::vector<PluginCandidate> out;
  std::vector<std::string> seen_types;
  for (const auto& dir : paths_) {
    std::error_code ec;
    if (!fs::is_directory(dir, ec)) continue;
    std::vector<fs::path> files;
    for (const auto& e : fs::directory_iterator(dir, ec))
      if (e.path().extension() == ".so") files.push_back(e.path());
    std::sort(files.begin(), files.end());
    for (const auto& f : files) {
      PluginCandidate c;
      c.path = f.string();
      try {
        auto lib = openLibrary(c.path);
        c.type = lib->type;
        c.version = lib->version;
        c.description = lib->description;
        if (lib->type != f.stem().string()) {
          c.reason = "file name '" + f.filename().string() + "' does not match its plugin type '" + lib->type +
                     "' (it would never be found as '" + lib->type + "')";
        } else if (std::find(seen_types.begin(), seen_types.end(), lib->type) != seen_types.end()) {
          c.reason = "shadowed by an earlier '" + lib->type + "' on the search path";
        } else {
          c.ok = true;
          seen_types.push_back(lib->type);
        }
      } catch (const PluginError& e) {
        c.reason = e.what();
      }
      out.push_back(std::move(c));
    }
  }
  return out;
}

std::vector<std::string> PluginRegistry::availableTypes() const {
  std::vector<std::string> out;
  for (const auto& c : scan())
    if (c.ok) out.push_back(c.type);
  return out;
}

PluginHandle PluginRegistry::create(const std::string& type) const {
  const std::string path = find(type);
  if (path.empty()) {
    const auto types = availableTypes();
    throw PluginError("unknown plugin type '" + type + "'" + didYouMean(type, types) + "; available: [" +
                      joinStrings(types) + "]; searched: " + joinStrings(paths_, ":"));
  }
  return createFromFile(path, type);
}

PluginHandle PluginRegistry::createFromFile(const std::string& path, const std::string& expected_type) {
  auto lib = openLibrary(path);
  if (!expected_type.empty() && lib->type != expected_type)
    throw PluginError(path + ": plugin type mismatch: expected '" + expected_type + "', found '" + lib->type + "'");
  return instantiate(lib);
}

}  // namespace terramap
