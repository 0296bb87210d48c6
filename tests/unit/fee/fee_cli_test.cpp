// `terramap fee` end to end: runs the built binary (skipped when it has not been built).
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>

namespace {

struct CliRun {
  int code = -1;
  std::string out;
};

std::string binary() { return std::string(TERRAMAP_BINARY_DIR) + "/bin/terramap"; }

CliRun runFee(const std::string& args) {
  CliRun r;
  const std::string cmd = binary() + " fee " + args + " 2>/dev/null";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  size_t n;
  while ((n = fread(buf, 1, sizeof buf, p)) > 0) r.out.append(buf, n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

const char* kCoulomb =
    "--c-pa 0 --phi-deg 30 --gamma-n-m3 18000 --ca-pa 0 --delta-deg 20 --alpha-deg 0 --rho-deg 90 "
    "--d-m 1 --w-m 1 --q-n 0";

class FeeCli : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!std::ifstream(binary()).good()) GTEST_SKIP() << binary() << " not built";
  }
};

TEST_F(FeeCli, ValidCasePrintsAllKeysInOrderAndExitsZero) {
  const CliRun r = runFee(kCoulomb);
  ASSERT_EQ(r.code, 0) << r.out;
  const auto j = nlohmann::ordered_json::parse(r.out);
  const char* keys[] = {"beta_rad", "eta_rad", "N_gamma", "N_c", "N_Q", "N_ca", "f_N",
                        "Fx_N", "Fz_N", "Fx_total_N", "Fz_total_N", "valid", "reason"};
  ASSERT_EQ(j.size(), 13u);
  int i = 0;
  for (auto it = j.begin(); it != j.end(); ++it, ++i) EXPECT_EQ(it.key(), keys[i]);
  EXPECT_TRUE(j["valid"].get<bool>());
  // Coulomb passive: f = 1/2 gamma H^2 K_p with K_p = 6.1054 (phi 30, delta 20, vertical wall).
  const double phi = 30 * M_PI / 180, delta = 20 * M_PI / 180;
  const double root = std::sqrt(std::sin(phi + delta) * std::sin(phi) / std::cos(delta));
  const double kp = std::pow(std::cos(phi), 2) / (std::cos(delta) * std::pow(1 - root, 2));
  EXPECT_NEAR(j["f_N"].get<double>(), 9000 * kp, 1e-6);
  EXPECT_NEAR(j["Fx_N"].get<double>(), 9000 * kp * std::cos(delta), 1e-6);
}

TEST_F(FeeCli, NominalBetaAndExplicitBeta) {
  const CliRun a = runFee(std::string(kCoulomb) + " --beta nominal");
  ASSERT_EQ(a.code, 0);
  EXPECT_NEAR(nlohmann::json::parse(a.out)["beta_rad"].get<double>(), M_PI / 6, 1e-15);
  const CliRun b = runFee(std::string(kCoulomb) + " --beta-deg 25");
  ASSERT_EQ(b.code, 0);
  EXPECT_NEAR(nlohmann::json::parse(b.out)["beta_rad"].get<double>(), 25 * M_PI / 180, 1e-15);
}

TEST_F(FeeCli, InvalidExitsEightWithReason) {
  const CliRun r = runFee(
      "--c-pa 0 --phi-deg 30 --gamma-n-m3 18000 --ca-pa 0 --delta-deg 20 --alpha-deg 0 --rho-deg 90 "
      "--d-m -0.2 --w-m 1 --q-n 0");
  EXPECT_EQ(r.code, 8);
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_FALSE(j["valid"].get<bool>());
  EXPECT_NE(j["reason"].get<std::string>().find("DepthNotPositive"), std::string::npos);
  EXPECT_NE(j["reason"].get<std::string>().find("d > 0"), std::string::npos);
}

TEST_F(FeeCli, UsageErrors) {
  EXPECT_EQ(runFee(std::string(kCoulomb) + " --beta-deg 20 --beta min").code, 2);
  EXPECT_EQ(runFee(std::string(kCoulomb) + " --beta sideways").code, 2);
  EXPECT_EQ(runFee("--c-pa 0").code, 2);  // required options missing
}

}  // namespace
