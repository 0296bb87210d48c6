// The exported-symbol table read from a plugin file before it is loaded: what the
// loader refuses a library for without running any of its code.
#include <terramap/core/error.hpp>
#include <terramap/pipeline/plugin_loader.hpp>

#include <gtest/gtest.h>

#include <pipeline/elf_section.hpp>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>

#include <unistd.h>

using namespace terramap;

namespace {
const std::string kTestDir = TERRAMAP_TEST_PLUGIN_DIR;
std::string lib(const std::string& n) { return kTestDir + "/" + n + ".so"; }
bool has(const std::vector<std::string>& v, const std::string& s) { return std::find(v.begin(), v.end(), s) != v.end(); }
}  // namespace

TEST(ElfSymbols, ReadsWhatAPluginExportsWithoutLoadingIt) {
  const auto good = detail::readElfExportedSymbols(lib("test_probe"));
  ASSERT_TRUE(good.has_value());
  EXPECT_TRUE(has(*good, "terramap_plugin_info"));
  EXPECT_TRUE(has(*good, "terramap_plugin_create"));
  EXPECT_TRUE(has(*good, "terramap_plugin_destroy"));
  const auto missing = detail::readElfExportedSymbols(lib("marked_missing_symbol"));
  ASSERT_TRUE(missing.has_value());
  EXPECT_TRUE(has(*missing, "terramap_plugin_info"));
  EXPECT_FALSE(has(*missing, "terramap_plugin_create"));
  EXPECT_FALSE(detail::readElfExportedSymbols(lib("test_probe") + ".missing").has_value());
}

TEST(ElfSymbols, AMissingSymbolIsRefusedBeforeTheLibraryRuns) {
  try {
    PluginRegistry::createFromFile(lib("marked_missing_symbol"));
    FAIL();
  } catch (const PluginError& e) {
    EXPECT_NE(std::string(e.what()).find("missing symbol 'terramap_plugin_create'"), std::string::npos) << e.what();
  }
  EXPECT_EQ(std::getenv("TERRAMAP_TEST_LOADED_marked_missing_symbol"), nullptr) << "its constructor ran";
}

TEST(ElfSymbols, TruncatedOrCorruptFilesGiveNoTableAndAreRefusedUnloaded) {
  std::ifstream in(lib("test_probe"), std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), {});
  const auto dir = std::filesystem::temp_directory_path() / ("terramap_elf_symbols_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string cut = (dir / "cut.so").string();
  for (std::size_t n : {std::size_t{0}, std::size_t{64}, bytes.size() / 3, bytes.size() - 1}) {
    std::ofstream(cut, std::ios::binary | std::ios::trunc).write(bytes.data(), static_cast<std::streamsize>(n));
    EXPECT_FALSE(detail::readElfExportedSymbols(cut).has_value()) << n << " bytes";
    try {
      PluginRegistry::createFromFile(cut);
      ADD_FAILURE() << n;
    } catch (const PluginError& e) {
      EXPECT_NE(std::string(e.what()).find("cannot load plugin library"), std::string::npos) << e.what();
    }
  }
  std::filesystem::remove_all(dir);
}

TEST(ElfSymbols, DidYouMeanLoadsNothing) {
  const auto dir = std::filesystem::temp_directory_path() / ("terramap_did_you_mean_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  std::filesystem::copy_file(lib("marked_probe"), dir / "test_probe.so",
                             std::filesystem::copy_options::overwrite_existing);
  try {
    PluginRegistry({dir.string()}).create("test_prob");
    FAIL();
  } catch (const PluginError& e) {
    EXPECT_NE(std::string(e.what()).find("did you mean 'test_probe'"), std::string::npos) << e.what();
  }
  EXPECT_EQ(std::getenv("TERRAMAP_TEST_LOADED_marked_probe"), nullptr) << "a library was loaded for the suggestion";
  std::filesystem::remove_all(dir);
}
