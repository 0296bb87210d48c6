// Source paths that begin with one of terramap's environment variables (${TERRAMAP_NAME} or
// ${TERRAMAP_NAME:-default}): how configs/kitti.yaml finds data that cannot ship with it.
#include <terramap/core/error.hpp>
#include <terramap/pipeline/pipeline_spec.hpp>
#include <terramap/pipeline/source.hpp>

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

using namespace terramap;
namespace fs = std::filesystem;

namespace {

constexpr const char* kVar = "TERRAMAP_TEST_SOURCE_DIR";

/// A folder `dir/name` with two KITTI scans of one point each.
fs::path cloudFolder(const fs::path& dir, const std::string& name) {
  const fs::path f = dir / name;
  fs::create_directories(f);
  const float p[4] = {1.f, 2.f, 3.f, 0.5f};
  for (const char* n : {"000000.bin", "000001.bin"}) std::ofstream(f / n, std::ios::binary).write(reinterpret_cast<const char*>(p), sizeof p);
  return f;
}

fs::path scratch(const std::string& tag) {
  const fs::path d = fs::path(TERRAMAP_BINARY_DIR) / "test_tmp" / ("source_paths_" + tag);
  fs::remove_all(d);
  fs::create_directories(d);
  return d;
}

/// The pipeline `dir/p.yaml` with this `clouds:` value, made into its source; the clouds counted.
long cloudsOf(const fs::path& dir, const std::string& clouds) {
  std::ofstream(dir / "p.yaml") << "version: 1\nmap: {resolution: 0.1, size: [20, 20]}\n"
                                   "source: {type: sequence, clouds: '" << clouds << "', extensions: [.bin]}\npipeline: []\n";
  const auto src = makeSource(parsePipelineFile((dir / "p.yaml").string()));
  long n = 0;
  Event e;
  while (src->next(e)) n += std::holds_alternative<PointCloud>(e) ? 1 : 0;
  return n;
}

std::string configError(const fs::path& dir, const std::string& clouds) {
  try {
    cloudsOf(dir, clouds);
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "(no error)";
}

struct EnvScope {
  explicit EnvScope(const char* value) {
    if (value) ::setenv(kVar, value, 1);
    else ::unsetenv(kVar);
  }
  ~EnvScope() { ::unsetenv(kVar); }
};

}  // namespace

TEST(SourcePaths, TheVariablesValueWinsOverTheDefault) {
  const fs::path d = scratch("set");
  cloudFolder(d, "elsewhere");
  cloudFolder(d, "default");
  const EnvScope env((d / "elsewhere").c_str());
  fs::remove(d / "elsewhere" / "000001.bin");  // one scan there, two in the default
  EXPECT_EQ(cloudsOf(d, "${TERRAMAP_TEST_SOURCE_DIR:-default}"), 1);
  EXPECT_EQ(cloudsOf(d, "${TERRAMAP_TEST_SOURCE_DIR}"), 1);
}

TEST(SourcePaths, UnsetOrEmptyTheDefaultIsRelativeToThePipelineFile) {
  const fs::path d = scratch("default");
  cloudFolder(d, "default");
  {
    const EnvScope env(nullptr);
    EXPECT_EQ(cloudsOf(d, "${TERRAMAP_TEST_SOURCE_DIR:-default}"), 2);
  }
  const EnvScope empty("");
  EXPECT_EQ(cloudsOf(d, "${TERRAMAP_TEST_SOURCE_DIR:-default}"), 2);
}

TEST(SourcePaths, ARelativeValueIsTakenFromTheCurrentFolder) {
  const fs::path d = scratch("relative");
  cloudFolder(d, "here");
  const fs::path old = fs::current_path();
  fs::current_path(d);
  const EnvScope env("here");
  long n = -1;
  EXPECT_NO_THROW(n = cloudsOf(d / "here", "${TERRAMAP_TEST_SOURCE_DIR}"));  // the file lives in here/ itself
  fs::current_path(old);
  EXPECT_EQ(n, 2);
}

TEST(SourcePaths, MissingDataNamesThePathAndTheSetting) {
  const fs::path d = scratch("missing");
  {
    const EnvScope env(nullptr);
    const std::string e = configError(d, "${TERRAMAP_TEST_SOURCE_DIR:-nowhere}");
    EXPECT_NE(e.find((d / "nowhere").string() + "' does not exist"), std::string::npos) << e;
    EXPECT_NE(e.find("TERRAMAP_TEST_SOURCE_DIR is not set, so the default was used"), std::string::npos) << e;
    const std::string no_default = configError(d, "${TERRAMAP_TEST_SOURCE_DIR}");
    EXPECT_NE(no_default.find("TERRAMAP_TEST_SOURCE_DIR is not set and '${TERRAMAP_TEST_SOURCE_DIR}' gives no default"),
              std::string::npos)
        << no_default;
  }
  const EnvScope env((d / "gone").c_str());
  const std::string e = configError(d, "${TERRAMAP_TEST_SOURCE_DIR:-nowhere}");
  EXPECT_NE(e.find("TERRAMAP_TEST_SOURCE_DIR is '" + (d / "gone").string() + "'"), std::string::npos) << e;
  EXPECT_NE(e.find("source.clouds"), std::string::npos) << e;
}

TEST(SourcePaths, OnlyTerramapsOwnVariablesAndOnlyAtTheStart) {
  const fs::path d = scratch("refused");
  cloudFolder(d, "default");
  EXPECT_NE(configError(d, "${HOME}").find("only terramap's own variables may begin a path"), std::string::npos);
  EXPECT_NE(configError(d, "${TERRAMAP_}").find("only terramap's own variables"), std::string::npos);
  EXPECT_NE(configError(d, "${terramap_x:-default}").find("only terramap's own variables"), std::string::npos);
  EXPECT_NE(configError(d, "default/${TERRAMAP_TEST_SOURCE_DIR}").find("a variable may only begin the path"),
            std::string::npos);
  EXPECT_NE(configError(d, "${TERRAMAP_TEST_SOURCE_DIR:-default").find("a variable may only begin the path"),
            std::string::npos);
  // A path without "${" is an ordinary path, whatever else it holds.
  EXPECT_EQ(cloudsOf(d, "default"), 2);
}
