#include <terramap/core/error.hpp>
#include <terramap/pipeline/engine.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <pipeline/elf_section.hpp>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

using namespace terramap;

namespace {
const std::string kTestDir = TERRAMAP_TEST_PLUGIN_DIR;
std::string lib(const std::string& n) { return kTestDir + "/" + n + ".so"; }

std::string loadError(const std::string& name) {
  try {
    PluginRegistry::createFromFile(lib(name));
  } catch (const PluginError& e) {
    return e.what();
  }
  return "";
}
void expectHas(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "expected '" << part << "' in:\n" << msg;
}

EngineOptions smallMap() {
  EngineOptions o;
  o.geometry = Geometry(0.1, Size(40, 30));
  o.map.tile_size = 16;
  o.threads = 2;
  o.layers = {LayerDecl{"elevation", "m", std::numeric_limits<float>::quiet_NaN(), ""}};
  return o;
}
}  // namespace

TEST(PluginLoader, LoadsAGoodPlugin) {
  PluginHandle h = PluginRegistry::createFromFile(lib("test_probe"));
  ASSERT_TRUE(h);
  EXPECT_EQ(h.type(), "test_probe");
  EXPECT_EQ(h.version(), "0.0.1");
  EXPECT_FALSE(h->schema().empty());
}

TEST(PluginLoader, WrongAbiNumberIsRefusedWithBothValues) {
  const auto m = loadError("bad_abi");
  expectHas(m, lib("bad_abi"));
  expectHas(m, "ABI version mismatch: expected " + std::to_string(TERRAMAP_PLUGIN_ABI_VERSION) + ", found 99");
}

TEST(PluginLoader, WrongRecordSizeIsRefusedWithBothValues) {
  const auto m = loadError("bad_size");
  expectHas(m, lib("bad_size"));
  expectHas(m, "info record size mismatch: expected " + std::to_string(sizeof(terramap_plugin_info_t)) +
                   " bytes, found " + std::to_string(sizeof(terramap_plugin_info_t) + 8));
}

TEST(PluginLoader, WrongFingerprintIsRefusedWithBothValues) {
  const auto m = loadError("bad_fingerprint");
  expectHas(m, "build fingerprint mismatch: expected '" + std::string(TERRAMAP_BUILD_FINGERPRINT) +
                   "', found 'terramap-0.1;othercc-1;cxx11abi-0;eigen-3.0.0'");
}

TEST(PluginLoader, MissingSymbolIsRefused) {
  const auto m = loadError("bad_missing_symbol");
  expectHas(m, lib("bad_missing_symbol"));
  expectHas(m, "missing symbol 'terramap_plugin_create'");
}

TEST(PluginLoader, NotALibraryOrNotAPlugin) {
  expectHas(loadError("does_not_exist"), "cannot load plugin library");
  // A shared library that is not a plugin at all: the core library itself.
  try {
    PluginRegistry::createFromFile(std::string(TERRAMAP_BINARY_DIR) + "/lib/libterramap_core.so");
    FAIL();
  } catch (const PluginError& e) {
    expectHas(e.what(), "missing symbol 'terramap_plugin_info'");
  }
}

TEST(PluginLoader, ThrowingConfigureIsReportedAsPluginError) {
  PluginHandle h = PluginRegistry::createFromFile(lib("bad_throwing_configure"));
  try {
    Engine::prepare("t", std::move(h), {});
    FAIL();
  } catch (const PluginError& e) {
    expectHas(e.what(), "threw in configure(): configure exploded on purpose");
  }
}

TEST(PluginLoader, RegistryFindsByTypeWithDidYouMeanAndExplainsRefusals) {
  PluginRegistry reg({kTestDir});
  EXPECT_EQ(reg.find("test_probe"), lib("test_probe"));
  try {
    reg.create("test_prob");
    FAIL();
  } catch (const PluginError& e) {
    expectHas(e.what(), "unknown plugin type 'test_prob' (did you mean 'test_probe'?)");
    expectHas(e.what(), kTestDir);
  }
  int refused = 0;
  bool misnamed = false;
  for (const auto& c : reg.scan()) {
    if (!c.ok) ++refused;
    if (c.path == lib("misnamed")) {
      misnamed = true;
      EXPECT_FALSE(c.ok);
      expectHas(c.reason, "does not match its plugin type 'something_else'");
    }
  }
  EXPECT_TRUE(misnamed);
  EXPECT_GE(refused, 5);  // abi, size, fingerprint, missing symbol, misnamed
}

TEST(PluginLoader, EnvironmentVariableIsSearched) {
  setenv("TERRAMAP_PLUGIN_PATH", (std::string("/nonexistent:") + kTestDir).c_str(), 1);
  PluginRegistry reg;
  unsetenv("TERRAMAP_PLUGIN_PATH");
  EXPECT_EQ(reg.find("test_probe"), lib("test_probe"));
  EXPECT_EQ(reg.searchPaths().back(), PluginRegistry::defaultPluginDir());
}

TEST(PluginLoader, RefusedPluginsLeaveTheEngineUnchanged) {
  Engine engine(smallMap());
  engine.addStage("p", PluginRegistry::createFromFile(lib("test_probe")), {{"increment", 2.0}});
  engine.push(Tick{1.0});
  const auto before = engine.snapshot();
  const auto names_before = engine.stageNames();

  for (const char* bad : {"bad_abi", "bad_size", "bad_fingerprint", "bad_missing_symbol"})
    EXPECT_THROW(engine.addStage("x", PluginRegistry::createFromFile(lib(bad))), PluginError) << bad;
  EXPECT_THROW(engine.addStage("x", PluginRegistry::createFromFile(lib("bad_throwing_configure"))), PluginError);
  // Bad params, a duplicate layer and a duplicate name are refused too.
  EXPECT_THROW(engine.addStage("y", PluginRegistry::createFromFile(lib("test_probe")), {{"incremnt", 1.0}}),
               ConfigError);
  EXPECT_THROW(engine.addStage("p2", PluginRegistry::createFromFile(lib("test_probe"))), ConfigError);  // 'probe' exists
  EXPECT_THROW(engine.addStage("p", PluginRegistry::createFromFile(lib("test_probe")),
                               {{"output_layer", std::string("other")}}),
               ConfigError);
  EXPECT_THROW(engine.addStage("z", PluginRegistry::createFromFile(lib("test_probe")),
                               {{"output_layer", std::string("z")}, {"input_layer", std::string("nope")}}),
               ConfigError);

  EXPECT_EQ(engine.stageNames(), names_before);
  const auto after = engine.snapshot();
  ASSERT_EQ(after->layerNames(), before->layerNames());
  for (LayerId l = 0; l < after->layerCount(); ++l) {
    const Eigen::MatrixXf a = after->toMatrix(l), b = before->toMatrix(l);
    EXPECT_EQ(std::memcmp(a.data(), b.data(), sizeof(float) * static_cast<size_t>(a.size())), 0);
  }
  // And it still runs exactly as before.
  engine.push(Tick{2.0});
  EXPECT_EQ(engine.map().at(engine.map().layerId("probe"), Index(3, 3)), 4.0f);
}

// ---- flags that must match (docs/plugins.md, "Compile flags") ------------------------------

namespace {
bool ranCode(const std::string& name) { return std::getenv(("TERRAMAP_TEST_LOADED_" + name).c_str()) != nullptr; }
std::string fileBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}
}  // namespace

TEST(PluginLoader, EveryPluginCarriesItsFingerprintInTheAbiSection) {
  // Every built-in plugin module and the test probe.
  std::vector<std::string> modules = {lib("test_probe")};
  for (const auto& e : std::filesystem::directory_iterator(TERRAMAP_PLUGIN_DIR))
    if (e.path().extension() == ".so") modules.push_back(e.path().string());
  ASSERT_GE(modules.size(), 6u);  // blade_sweep, inpaint, lidar_fusion, smooth_filter, soil_erosion + probe
  for (const std::string& m : modules) {
    const auto note = detail::readElfSection(m, TERRAMAP_PLUGIN_ABI_SECTION);
    ASSERT_TRUE(note.has_value()) << m;
    EXPECT_STREQ(note->c_str(), TERRAMAP_BUILD_FINGERPRINT) << m;
  }
  // The host pins Eigen's alignment (CMake package) and says so in the fingerprint.
  EXPECT_NE(std::string(TERRAMAP_BUILD_FINGERPRINT).find(";eigen-align-16-16;"), std::string::npos);
}

TEST(PluginLoader, OtherEigenAlignmentIsRefusedBeforeAnyOfItsCodeRuns) {
  const auto m = loadError("bad_eigen_align");
  expectHas(m, lib("bad_eigen_align"));
  expectHas(m, "build fingerprint mismatch (read before loading): expected '" + std::string(TERRAMAP_BUILD_FINGERPRINT));
  expectHas(m, "eigen-align-32-32");
  expectHas(m, "Eigen's maximum alignment");
  EXPECT_FALSE(ranCode("bad_eigen_align")) << "the library was loaded (its constructor ran)";
}

TEST(PluginLoader, SanitizedPluginInAPlainHostIsRefusedNotAborted) {
  if (!std::filesystem::exists(lib("bad_sanitizer"))) GTEST_SKIP() << "host built with a sanitizer";
  const auto m = loadError("bad_sanitizer");  // dlopen() would abort this process
  expectHas(m, lib("bad_sanitizer"));
  expectHas(m, "asan-1");
  expectHas(m, "sanitizer");
  EXPECT_FALSE(ranCode("bad_sanitizer"));
}

TEST(PluginLoader, FastMathPluginIsRefusedAndTheFloatingPointStateRestored) {
#if defined(__SSE__)
  const unsigned before = _mm_getcsr();
#endif
  const auto m = loadError("bad_fast_math");
  expectHas(m, lib("bad_fast_math"));
  expectHas(m, "changed the floating-point environment");
  expectHas(m, "flush-to-zero denormals-are-zero");
  expectHas(m, "-ffast-math");
  EXPECT_TRUE(ranCode("bad_fast_math")) << "refused for another reason than its constructor";
#if defined(__SSE__)
  EXPECT_EQ(_mm_getcsr() & ~0x3Fu, before & ~0x3Fu) << "flush-to-zero left set on the loading thread";
#endif
  // A denormal survives arithmetic on this thread (FTZ would flush it to zero).
  volatile float tiny = 1e-39f;
  EXPECT_GT(tiny * 1.0f, 0.0f);
}

TEST(ElfSection, ReadsNothingFromFilesThatAreNotWholeElfLibraries) {
  const std::string good = lib("test_probe");
  ASSERT_TRUE(detail::readElfSection(good, TERRAMAP_PLUGIN_ABI_SECTION).has_value());
  EXPECT_FALSE(detail::readElfSection(good, ".no_such_section").has_value());
  EXPECT_FALSE(detail::readElfSection(good + ".missing", TERRAMAP_PLUGIN_ABI_SECTION).has_value());
  const std::string bytes = fileBytes(good);
  const auto dir = std::filesystem::temp_directory_path() / "terramap_elf_section_test";
  std::filesystem::create_directories(dir);
  const std::string cut = (dir / "cut.so").string();
  // Truncated anywhere (header, section table, string table): no section, no crash.
  for (std::size_t n : {std::size_t{0}, std::size_t{3}, std::size_t{40}, std::size_t{64}, bytes.size() / 2,
                        bytes.size() - 1}) {
    std::ofstream(cut, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(n));
    EXPECT_FALSE(detail::readElfSection(cut, TERRAMAP_PLUGIN_ABI_SECTION).has_value()) << n << " bytes";
  }
  // Header fields pointing outside the file.
  std::string bad = bytes;
  std::memset(&bad[0x28], 0xff, 8);  // e_shoff (ELF64)
  std::ofstream(cut, std::ios::binary | std::ios::trunc).write(bad.data(), static_cast<std::streamsize>(bad.size()));
  EXPECT_FALSE(detail::readElfSection(cut, TERRAMAP_PLUGIN_ABI_SECTION).has_value());
  std::filesystem::remove_all(dir);
}
