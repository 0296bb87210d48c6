#include <terramap/pipeline/plugin_loader.hpp>
#include <terramap/core/text.hpp>

#include "elf_section.hpp"

#define BOOST_DLL_USE_STD_FS
#include <boost/dll/runtime_symbol_info.hpp>
#include <boost/dll/shared_library.hpp>

#include <algorithm>
#include <cctype>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <mutex>
#include <sstream>

#include <cfenv>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

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

std::vector<std::string> fingerprintFields(const std::string& fp) {
  std::vector<std::string> out;
  std::stringstream ss(fp);
  std::string f;
  while (std::getline(ss, f, ';')) out.push_back(f);
  return out;
}

/// What to do about one fingerprint field that differs. Its key is the text before the first
/// '-' that a digit follows ("eigen-align-16-16" -> "eigen-align", "gcc-12" -> "gcc").
std::string fieldAdvice(const std::string& field) {
  std::size_t cut = 0;
  while ((cut = field.find('-', cut)) != std::string::npos && cut + 1 < field.size() &&
         !std::isdigit(static_cast<unsigned char>(field[cut + 1])))
    ++cut;
  const std::string key = field.substr(0, cut);
  if (key == "eigen-align")
    return "Eigen's maximum alignment (EIGEN_MAX_ALIGN_BYTES-EIGEN_MAX_STATIC_ALIGN_BYTES) differs: SIMD "
           "flags such as -mavx or -march=native raise it unless EIGEN_MAX_ALIGN_BYTES=16 is defined, "
           "which terramap::plugin_api does for plugins built with find_package(terramap)";
  if (key == "asan" || key == "tsan")
    return "host and plugin must both be built with the sanitizer or both without it "
           "(TERRAMAP_SANITIZE is exported by the installed package)";
  if (key == "glibcxx-debug") return "_GLIBCXX_DEBUG changes the layout of every std container";
  if (key == "cxx11abi") return "the libstdc++ string ABI (_GLIBCXX_USE_CXX11_ABI) differs";
  if (key == "eigen") return "built against another Eigen version";
  if (key == "terramap") return "built against another terramap version";
  return "built with another compiler or compiler major version";
}

/// The refusal for a fingerprint that differs, naming each differing field and its cause.
PluginError fingerprintMismatch(const std::string& path, const std::string& found, const char* when) {
  std::string msg = path + ": plugin build fingerprint mismatch" + when + ": expected '" +
                    std::string(TERRAMAP_BUILD_FINGERPRINT) + "', found '" + found + "'";
  const auto want = fingerprintFields(TERRAMAP_BUILD_FINGERPRINT), got = fingerprintFields(found);
  std::vector<std::string> reasons;
  for (std::size_t i = 0; i < std::max(want.size(), got.size()); ++i) {
    const std::string w = i < want.size() ? want[i] : "", g = i < got.size() ? got[i] : "";
    if (w == g) continue;
    const std::string advice = fieldAdvice(w.empty() ? g : w);
    if (std::find(reasons.begin(), reasons.end(), advice) == reasons.end()) reasons.push_back(advice);
  }
  for (const auto& r : reasons) msg += "; " + r;
  return PluginError(msg + " (rebuild the plugin with the host's compiler, flags and terramap version)");
}

/// The floating-point environment a library's load may change for the loading thread: the
/// rounding mode and, on x86, MXCSR (flush-to-zero and denormals-are-zero). A library linked
/// with -ffast-math/-Ofast by GCC < 13 sets FTZ/DAZ from a constructor; that would make the
/// host's results depend on which thread loaded the plugin.
/// Only MXCSR's control bits count (DAZ, exception masks, rounding, FTZ); its low six bits are
/// sticky exception *status* flags that any inexact operation in a library's initialisers sets
/// (loading libtorch sets "inexact"), which changes no result.
struct FpState {
  static constexpr unsigned kMxcsrStatus = 0x3Fu;
  int rounding = std::fegetround();
#if defined(__SSE__)
  unsigned mxcsr = _mm_getcsr() & ~kMxcsrStatus;
#else
  unsigned mxcsr = 0;
#endif
  bool operator==(const FpState& o) const { return rounding == o.rounding && mxcsr == o.mxcsr; }
  void restore() const {
    std::fesetround(rounding);
#if defined(__SSE__)
    _mm_setcsr((_mm_getcsr() & kMxcsrStatus) | mxcsr);
#endif
  }
};

std::string fpStateText(const FpState& s) {
  std::ostringstream os;
  os << "rounding " << s.rounding << ", MXCSR control 0x" << std::hex << s.mxcsr;
  if (s.mxcsr & 0x8000u) os << " flush-to-zero";
  if (s.mxcsr & 0x40u) os << " denormals-are-zero";
  return os.str();
}

/// Everything that can be refused from the file alone, before dlopen() runs any of its code
/// (constructors run at load, before any symbol could be asked for). Throws PluginError.
void checkBeforeLoading(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) throw PluginError(path + ": cannot load plugin library: no such file");
  const auto symbols = detail::readElfExportedSymbols(path);
  if (!symbols)
    throw PluginError(path + ": cannot load plugin library: not an ELF shared library of this machine, or its "
                      "section or dynamic symbol table cannot be read (a plugin's symbols are read before it is loaded)");
  auto exports = [&](const char* s) { return std::binary_search(symbols->begin(), symbols->end(), std::string(s)); };
  if (!exports(kPluginInfoSymbol))
    throw PluginError(path + ": missing symbol '" + std::string(kPluginInfoSymbol) +
                      "': not a terramap plugin (export it with TERRAMAP_PLUGIN)");
  if (const auto note = detail::readElfSection(path, TERRAMAP_PLUGIN_ABI_SECTION)) {
    const std::string found(note->c_str());  // up to the NUL
    if (found != TERRAMAP_BUILD_FINGERPRINT) throw fingerprintMismatch(path, found, " (read before loading)");
  }
  for (const char* sym : {kPluginCreateSymbol, kPluginDestroySymbol})
    if (!exports(sym))
      throw PluginError(path + ": missing symbol '" + std::string(sym) + "' (export it with TERRAMAP_PLUGIN)");
}

struct TrustSettings {
  std::mutex mu;
  bool allow_config_paths = false;
  std::vector<std::string> cli_paths;
};
TrustSettings& trust() {
  static auto* t = new TrustSettings();  // never destroyed: registries may be made at exit
  return *t;
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

  checkBeforeLoading(path);
  auto lib = std::make_shared<PluginLibrary>();
  lib->path = path;
  const FpState fp_before;
  try {
    lib->lib.load(boost::dll::fs::path(path),
                  boost::dll::load_mode::rtld_now | boost::dll::load_mode::rtld_local);
  } catch (const std::exception& e) {
    throw PluginError(path + ": cannot load plugin library: " + e.what());
  }
  if (const FpState fp_after; !(fp_after == fp_before)) {
    fp_before.restore();
    throw PluginError(path + ": loading the plugin changed the floating-point environment (expected " +
                      fpStateText(fp_before) + ", found " + fpStateText(fp_after) +
                      "): it was linked with -ffast-math or -Ofast, which sets flush-to-zero for the "
                      "loading thread only and would make results depend on the thread; rebuild "
                      "without them (restored)");
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
  if (std::strcmp(fp, TERRAMAP_BUILD_FINGERPRINT) != 0) throw fingerprintMismatch(path, fp, "");
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
  {
    std::lock_guard<std::mutex> lock(trust().mu);
    paths_.insert(paths_.end(), trust().cli_paths.begin(), trust().cli_paths.end());
  }
  if (const char* env = std::getenv("TERRAMAP_PLUGIN_PATH")) {
    std::stringstream ss(env);
    std::string item;
    while (std::getline(ss, item, ':'))
      if (!item.empty()) paths_.push_back(item);
  }
  paths_.push_back(defaultPluginDir());
}

PluginRegistry PluginRegistry::forPipeline(const std::vector<std::string>& config_paths, const std::string& where) {
  if (!config_paths.empty() && !configPluginPathsAllowed())
    throw ConfigError(where + ": a pipeline file may not choose where plugins are loaded from (loading a library "
                      "runs its code): give the folders with --plugin-path or TERRAMAP_PLUGIN_PATH, or pass "
                      "--allow-config-plugin-paths if you trust this file (in code: "
                      "PluginRegistry::allowConfigPluginPaths; Python: terramap.allow_config_plugin_paths())");
  return PluginRegistry(config_paths);
}

void PluginRegistry::allowConfigPluginPaths(bool allow) {
  std::lock_guard<std::mutex> lock(trust().mu);
  trust().allow_config_paths = allow;
}

bool PluginRegistry::configPluginPathsAllowed() {
  std::lock_guard<std::mutex> lock(trust().mu);
  return trust().allow_config_paths;
}

void PluginRegistry::addTrustedPaths(const std::vector<std::string>& dirs) {
  std::lock_guard<std::mutex> lock(trust().mu);
  trust().cli_paths.insert(trust().cli_paths.end(), dirs.begin(), dirs.end());
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

namespace {
/// The .so files of a search folder in name order (none when it is not a folder).
std::vector<fs::path> soFilesIn(const std::string& dir) {
  std::vector<fs::path> files;
  std::error_code ec;
  if (!fs::is_directory(dir, ec)) return files;
  for (const auto& e : fs::directory_iterator(dir, ec))
    if (e.path().extension() == ".so") files.push_back(e.path());
  std::sort(files.begin(), files.end());
  return files;
}
}  // namespace

std::vector<PluginCandidate> PluginRegistry::scan() const {
  std::vector<PluginCandidate> out;
  std::vector<std::string> seen_types;
  for (const auto& dir : paths_) {
    for (const auto& f : soFilesIn(dir)) {
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
  // A did-you-mean for a mistyped `type:` must not run every library in the folders.
  std::vector<std::string> out;
  for (const auto& dir : paths_) {
    for (const auto& f : soFilesIn(dir)) {
      const std::string type = f.stem().string();
      if (std::find(out.begin(), out.end(), type) != out.end()) continue;
      try {
        checkBeforeLoading(f.string());
        out.push_back(type);
      } catch (const PluginError&) {  // NOLINT: a refused file is no suggestion; `terramap plugins` says why
      }
    }
  }
  return out;
}

std::string PluginRegistry::findOrThrow(const std::string& type) const {
  const std::string path = find(type);
  if (path.empty()) {
    const auto types = availableTypes();
    throw PluginError("unknown plugin type '" + type + "'" + didYouMean(type, types) + "; available: [" +
                      joinStrings(types) + "]; searched: " + joinStrings(paths_, ":"));
  }
  return path;
}

PluginFileDescription PluginRegistry::describe(const std::string& type) const {
  // A plugin's description is a few kB; the bound keeps a crafted section from costing memory.
  constexpr std::size_t kMaxSchemaBytes = 4u << 20;
  PluginFileDescription out;
  out.path = findOrThrow(type);
  checkBeforeLoading(out.path);
  const auto text = detail::readElfSection(out.path, TERRAMAP_PLUGIN_SCHEMA_SECTION, kMaxSchemaBytes);
  if (!text) {
    out.missing = "it has no embedded schema (section " TERRAMAP_PLUGIN_SCHEMA_SECTION
                  ", written by terramap_add_plugin when the plugin is built)";
    return out;
  }
  if (text->size() == kMaxSchemaBytes) {
    out.missing = "its embedded schema is larger than " + std::to_string(kMaxSchemaBytes) + " bytes";
    return out;
  }
  PluginDescription d;
  try {
    d = descriptionFromJson(*text, out.path);
  } catch (const InputError& e) {
    out.missing = e.what();
    return out;
  }
  // The description must be this file's own: the build-id is a hash of the linked code.
  const std::string id = elfBuildId(out.path);
  if (id.empty() || id != d.build_id) {
    out.missing = "its embedded schema was made for another build (build-id " + d.build_id + ", the file's " +
                  (id.empty() ? "none" : id) + ")";
    return out;
  }
  if (d.type != type)
    throw PluginError(out.path + ": plugin type mismatch: expected '" + type + "', found '" + d.type +
                      "' (in its embedded schema)");
  out.description = std::move(d);
  return out;
}

PluginHandle PluginRegistry::create(const std::string& type) const {
  return createFromFile(findOrThrow(type), type);
}

PluginHandle PluginRegistry::createFromFile(const std::string& path, const std::string& expected_type) {
  auto lib = openLibrary(path);
  if (!expected_type.empty() && lib->type != expected_type)
    throw PluginError(path + ": plugin type mismatch: expected '" + expected_type + "', found '" + lib->type + "'");
  return instantiate(lib);
}

}  // namespace terramap
