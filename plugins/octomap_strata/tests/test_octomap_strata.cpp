// octomap_strata: insertion by depth, inheritance and inflation against hand-computed values,
// pending and invalid estimates, the change depth, pruning, the .ot round trip and the octovis
// export, the plugin's layers and their bit-identity at 1 and 2 threads.
#include <gtest/gtest.h>

#include <octomap/AbstractOcTree.h>
#include <octomap/ColorOcTree.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>

#include "memory_budget_scope.hpp"
#include "octomap_strata.hpp"

#include <terramap/io/render.hpp>

using namespace terramap;
using namespace terramap::plugins;
using terramap::strata::CellCut;
using terramap::strata::SoilBelief;
using terramap::strata::SoilSource;
using terramap::strata::Strata;
using terramap::strata::StrataConfig;
using terramap::strata::SoilVector;

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

StrataConfig config() {
  StrataConfig c;
  c.resolution_m = 0.05;
  c.min_m = {-10, -10, -5};
  c.max_m = {10, 10, 5};
  c.inflation_depth_m = 0.2;
  c.prior_mean = {30e3, 0.5, 10e3, 0.4, 17e3};
  c.prior_var = {1e8, 0.04, 4e7, 0.02, 4e6};
  return c;
}

// One column-sized cell at (x, y) cut from `from` down to `to`.
CellCut cell(double x, double y, double from, double to, double size = 0.05) {
  CellCut c;
  c.position = {x, y};
  c.cell_m = size;
  c.old_surface_m = from;
  c.new_surface_m = to;
  return c;
}

double fusedMean(double m0, double v0, double z, double r) { return (r * m0 + v0 * z) / (v0 + r); }
double fusedVar(double v0, double r) { return v0 * r / (v0 + r); }

const SoilVector kEst{12e3, 0.6, 4e3, 0.35, 16e3};
const SoilVector kEstVar{4e6, 0.01, 1e6, 0.004, 1e6};

std::string tmp(const std::string& name) { return std::string(TERRAMAP_BINARY_DIR) + "/strata_test_" + name; }

}  // namespace

TEST(Strata, ACutRemovesTheVoxelsBetweenTheSurfacesAndTheyTakePriorTimesEstimate) {
  Strata s(config());
  // Voxel centres at (k + 0.5) 0.05: a cut from 1.0 to 0.8 removes 0.825, 0.875, 0.925, 0.975.
  EXPECT_EQ(s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)}), 4);
  EXPECT_FLOAT_EQ(static_cast<float>(s.surfaceAt(0.025, 0.025)), 0.8f);  // heights are kept as float
  EXPECT_FLOAT_EQ(static_cast<float>(s.initialSurfaceAt(0.025, 0.025)), 1.0f);
  // Before the estimate arrives the removed soil holds its prediction: the prior.
  SoilBelief b = s.soilAt(0.025, 0.025, 0.9);
  EXPECT_EQ(b.source, SoilSource::Predicted);
  EXPECT_FLOAT_EQ(static_cast<float>(b.mean[0]), 30e3f);
  EXPECT_EQ(s.assignEstimate(1, &kEst, &kEstVar), 4);
  const StrataConfig c = config();
  for (double z : {0.825, 0.875, 0.925, 0.975}) {
    b = s.soilAt(0.025, 0.025, z);
    ASSERT_EQ(b.source, SoilSource::Removed) << z;
    for (int q = 0; q < 5; ++q) {
      EXPECT_FLOAT_EQ(static_cast<float>(b.mean[q]), static_cast<float>(fusedMean(c.prior_mean[q], c.prior_var[q], kEst[q], kEstVar[q]))) << q;
      EXPECT_FLOAT_EQ(static_cast<float>(b.var[q]), static_cast<float>(fusedVar(c.prior_var[q], kEstVar[q]))) << q;
    }
  }
  EXPECT_EQ(s.soilAt(0.025, 0.025, 1.02).source, SoilSource::Air);   // above the first surface
  EXPECT_EQ(s.soilAt(0.075, 0.025, 0.9).source, SoilSource::Prior);  // the next column: never cut
  EXPECT_EQ(s.soilAt(11.0, 0.0, 0.9).source, SoilSource::Outside);
  EXPECT_TRUE(std::isnan(s.soilAt(11.0, 0.0, 0.9).mean[0]));
}

TEST(Strata, TheSoilBelowInheritsTheEstimateWithVarianceInflatedByDepth) {
  for (const bool prior_below : {false, true}) {
    StrataConfig c = config();
    c.prior_below = prior_below;
    Strata s(c);
    s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)});
    s.assignEstimate(1, &kEst, &kEstVar);
    for (double z : {0.8, 0.7, 0.5, 0.0}) {
      const SoilBelief b = s.soilAt(0.025, 0.025, z);
      ASSERT_EQ(b.source, SoilSource::Inherited);
      // By hand: e per 0.2 m below the anchor (the surface sweep 1 left, kept as a float).
      const double f = std::exp((static_cast<double>(0.8f) - z) / 0.2);
      for (int q = 0; q < 5; ++q) {
        // The column keeps the estimate as float.
        const double m = static_cast<float>(kEst[q]), v = static_cast<float>(kEstVar[q]);
        if (prior_below) {
          EXPECT_NEAR(b.mean[q], fusedMean(c.prior_mean[q], c.prior_var[q], m, v * f), 1e-12 * std::abs(c.prior_mean[q])) << z;
          EXPECT_NEAR(b.var[q], fusedVar(c.prior_var[q], v * f), 1e-12 * c.prior_var[q]) << z;
        } else {
          EXPECT_EQ(b.mean[q], m) << z;
          EXPECT_NEAR(b.var[q], v * f, 1e-12 * v * f) << z;
        }
      }
    }
    // Right under the cut the estimate; deep down the prior's mean again with prior_below, else
    // the estimate's mean with a variance far beyond the prior's.
    EXPECT_NEAR(s.soilAt(0.025, 0.025, 0.79).mean[0], 12e3, 2e3);
    EXPECT_NEAR(s.soilAt(0.025, 0.025, -2.0).mean[0], prior_below ? 30e3 : 12e3, 1e3) << prior_below;
    if (!prior_below) {
      EXPECT_GT(s.soilAt(0.025, 0.025, -2.0).var[0], 100 * c.prior_var[0]);
    }
  }
}

TEST(Strata, WithoutThePriorTheRemovedVoxelsHoldTheEstimateAsIsAndOlderFilesLoadAsTheyFused) {
  StrataConfig c = config();
  c.use_prior = false;
  Strata s(c);
  s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)});
  s.assignEstimate(1, &kEst, &kEstVar);
  for (double z : {0.825, 0.975}) {
    const SoilBelief b = s.soilAt(0.025, 0.025, z);
    ASSERT_EQ(b.source, SoilSource::Removed);
    for (int q = 0; q < 5; ++q) {
      EXPECT_FLOAT_EQ(static_cast<float>(b.mean[q]), static_cast<float>(kEst[q])) << q;
      EXPECT_FLOAT_EQ(static_cast<float>(b.var[q]), static_cast<float>(kEstVar[q])) << q;
    }
  }
  EXPECT_EQ(s.soilAt(0.075, 0.025, 0.9).source, SoilSource::Prior);  // never cut: the prior still
  EXPECT_EQ(s.soilAt(0.075, 0.025, 0.9).mean[0], c.prior_mean[0]);
  // The choice is part of the file: loaded, the soil is the same.
  const std::string path = tmp("no_prior.ot");
  s.save(path);
  EXPECT_EQ(Strata::load(path).soilAt(0.025, 0.025, 0.9).mean[0], s.soilAt(0.025, 0.025, 0.9).mean[0]);
  // Files of format 3 always fused the prior, in the removed voxels and below; format 4 in both
  // or neither: their trailers, without the flags they lacked, load so.
  StrataConfig both = config();
  both.prior_below = true;
  Strata fused(both);
  fused.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)});
  fused.assignEstimate(1, &kEst, &kEstVar);
  fused.save(path);
  std::string bytes;
  {
    std::ifstream i(path, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(i), std::istreambuf_iterator<char>());
  }
  const std::string v5 = "terramap_strata 5\n";
  const auto at = bytes.find(v5);
  ASSERT_NE(at, std::string::npos);
  const std::size_t flags = at + v5.size() + 8 * (1 + 3 + 3 + 1 + 5 + 5);  // resolution, extent, L, prior
  ASSERT_EQ(bytes[flags], 1);
  ASSERT_EQ(bytes[flags + 1], 1);
  for (const int format : {4, 3}) {
    std::string old = bytes;
    old.erase(flags + (format == 4 ? 1 : 0), format == 4 ? 1 : 2);
    old.replace(at, v5.size(), "terramap_strata " + std::to_string(format) + "\n");
    {
      std::ofstream o(path, std::ios::binary | std::ios::trunc);
      o << old;
    }
    const Strata r = Strata::load(path);
    for (double z : {0.9, 0.5})
      EXPECT_EQ(r.soilAt(0.025, 0.025, z).mean[0], fused.soilAt(0.025, 0.025, z).mean[0]) << format << " " << z;
  }
  EXPECT_NE(fused.soilAt(0.025, 0.025, 0.5).mean[0], s.soilAt(0.025, 0.025, 0.5).mean[0]);
}

TEST(Strata, TheInheritedBeliefFiltersEveryEstimateDownTheColumn) {
  const SoilVector second{30e3, 0.4, 8e3, 0.3, 18e3};
  for (const bool filter : {true, false}) {
    StrataConfig c = config();
    c.filter_inheritance = filter;
    Strata s(c);
    s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.9)});
    s.assignEstimate(1, &kEst, &kEstVar);
    s.applyCut(2, {cell(0.025, 0.025, 0.9, 0.8)});
    s.assignEstimate(2, &second, &kEstVar);
    // By hand: estimate 1 carried from 0.9 to 0.8 (variance × e^(0.1/0.2)), times estimate 2;
    // then, at z = 0.7, that carried another 0.1 m.
    const double a0 = 0.9f, a1 = 0.8f;
    for (int q = 0; q < 5; ++q) {
      // The column keeps its belief as float.
      double m = static_cast<float>(kEst[q]), v = static_cast<float>(kEstVar[q]) * std::exp((a0 - a1) / 0.2);
      if (filter) {
        const double mm = fusedMean(m, v, second[q], kEstVar[q]), vv = fusedVar(v, kEstVar[q]);
        m = static_cast<float>(mm);
        v = static_cast<float>(vv);
      } else {
        m = static_cast<float>(second[q]);
        v = static_cast<float>(kEstVar[q]);
      }
      const double f = std::exp((a1 - 0.7) / 0.2);
      const SoilBelief b = s.soilAt(0.025, 0.025, 0.7);
      EXPECT_NEAR(b.mean[q], m, 1e-9 * std::abs(m)) << q << filter;
      EXPECT_NEAR(b.var[q], v * f, 1e-9 * v * f) << q << filter;
    }
  }
}

TEST(Strata, AnInvalidEstimateLeavesThePredictionAndNoInheritance) {
  Strata s(config());
  s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)});
  s.assignEstimate(1, &kEst, &kEstVar);
  s.applyCut(2, {cell(0.025, 0.025, 0.8, 0.7)});
  // Pending: the removed voxels hold what was predicted for them (inherited from sweep 1).
  const SoilBelief before = s.soilAt(0.025, 0.025, 0.775);
  EXPECT_EQ(before.source, SoilSource::Predicted);
  EXPECT_NEAR(before.mean[0], s.soilAt(0.025, 0.025, 0.8).mean[0], 3e3);
  s.assignEstimate(2, nullptr, nullptr);
  EXPECT_EQ(s.soilAt(0.025, 0.025, 0.775).source, SoilSource::Predicted);
  EXPECT_EQ(s.counters().estimates_invalid, 1);
  // The soil below still inherits sweep 1's estimate, anchored where sweep 1 left the surface.
  const SoilBelief below = s.soilAt(0.025, 0.025, 0.6);
  const double f = std::exp((static_cast<double>(0.8f) - 0.6) / 0.2);
  EXPECT_NEAR(below.var[0], 4e6 * f, 1e-6);
  // An estimate for a sweep that cut nothing here is counted, not applied.
  EXPECT_EQ(s.assignEstimate(99, &kEst, &kEstVar), 0);
  EXPECT_EQ(s.counters().estimates_unmatched, 1);
}

TEST(Strata, PendingSweepsBeyondTheLimitKeepTheirPrediction) {
  StrataConfig c = config();
  c.max_pending_sweeps = 2;
  Strata s(c);
  for (int k = 0; k < 3; ++k) s.applyCut(k + 1, {cell(0.025 + 0.05 * k, 0.025, 1.0, 0.9)});
  EXPECT_EQ(s.pendingSweeps(), 2u);
  EXPECT_EQ(s.counters().pending_evicted, 1);
  EXPECT_EQ(s.assignEstimate(1, &kEst, &kEstVar), 0);  // evicted
  EXPECT_EQ(s.assignEstimate(2, &kEst, &kEstVar), 2);
}

TEST(Strata, TheChangeDepthIsWhereTheRemovedSoilChanges) {
  Strata s(config());
  const SoilVector loam{8e3, 0.5, 3e3, 0.35, 15e3}, clay{55e3, 0.42, 20e3, 0.3, 19e3};
  // Four cuts of 0.1 m; the soil changes after the second: 0.2 m below the first surface.
  const SoilVector* est[4] = {&loam, &loam, &clay, &clay};
  for (int k = 0; k < 4; ++k) {
    s.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.1 * k, 0.9 - 0.1 * k)});
    s.assignEstimate(k + 1, est[k], &kEstVar);
  }
  EXPECT_NEAR(s.changeDepthAt(0.025, 0.025), 0.2, 1e-6);  // heights are kept as float
  const auto vox = s.columnVoxels(0.025, 0.025);
  ASSERT_EQ(vox.size(), 8u);
  EXPECT_NEAR(vox.front().first, 0.975, 1e-9);
  EXPECT_NEAR(vox.back().first, 0.625, 1e-9);
  // One soil all the way down: no change.
  Strata u(config());
  for (int k = 0; k < 4; ++k) {
    u.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.1 * k, 0.9 - 0.1 * k)});
    u.assignEstimate(k + 1, &loam, &kEstVar);
  }
  EXPECT_TRUE(std::isnan(u.changeDepthAt(0.025, 0.025)));
}

TEST(Strata, AChangeBetweenSweepsIsPlacedWhereTheirSlabsMetNotOnAVoxelFace) {
  const SoilVector loam{8e3, 0.5, 3e3, 0.35, 15e3}, clay{55e3, 0.42, 20e3, 0.3, 19e3};
  // 4 cm slabs from 1.0 down; loam down to 0.84, clay below. Voxel centres 0.975 (slab 1),
  // 0.925 (2), 0.875 (4), 0.825 (5), ...; slab 3, (0.88, 0.92], holds no centre. The levels
  // split between 0.875 and 0.825 (face 0.85); the sweeps changed at 0.84.
  Strata s(config());
  for (int k = 0; k < 8; ++k) {
    s.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.04 * k, 0.96 - 0.04 * k)});
    s.assignEstimate(k + 1, k < 4 ? &loam : &clay, &kEstVar);
  }
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025), 0.84, 1e-6);
  EXPECT_NEAR(s.changeDepthAt(0.025, 0.025), 0.16, 1e-6);
  // A slab between the two soils that no voxel centre lay in (0.955 to 0.93): its soil is
  // unknown, so the change is halfway between where the loam's slabs ended (0.955) and the
  // clay's began (0.93), not on the face (0.95).
  Strata g(config());
  const double cuts[4][2] = {{1.0, 0.955}, {0.955, 0.93}, {0.93, 0.86}, {0.86, 0.80}};
  const SoilVector* est[4] = {&loam, &loam, &clay, &clay};
  for (int k = 0; k < 4; ++k) {
    g.applyCut(k + 1, {cell(0.025, 0.025, cuts[k][0], cuts[k][1])});
    g.assignEstimate(k + 1, est[k], &kEstVar);
  }
  ASSERT_EQ(g.columnVoxels(0.025, 0.025).size(), 4u);  // 0.975 | 0.925 0.875 | 0.825
  EXPECT_NEAR(g.changeHeightAt(0.025, 0.025), 0.5 * (0.955 + 0.93), 1e-6);
  const auto top = g.columnVoxels(0.025, 0.025).front().second;
  EXPECT_FLOAT_EQ(top.top, 1.0f);
  EXPECT_FLOAT_EQ(top.bottom, 0.955f);
}

TEST(Strata, ASweepThatCutAcrossTheChangeMovesItByTheFractionOfTheOtherSoil) {
  const SoilVector loam{8e3, 0.5, 3e3, 0.35, 15e3}, clay{55e3, 0.42, 20e3, 0.3, 19e3};
  SoilVector mix;  // a quarter clay
  for (int q = 0; q < 5; ++q) mix[q] = 0.75 * loam[q] + 0.25 * clay[q];
  // Five 5 cm slabs from 1.0: loam, loam, the mix (0.90 to 0.85), clay, clay. The mix is nearer
  // the loam, so the levels split below it (face 0.85); a quarter of its slab is clay, at its
  // bottom: the change is at 0.85 + 0.25 x 0.05.
  const SoilVector* est[5] = {&loam, &loam, &mix, &clay, &clay};
  Strata s(config());
  for (int k = 0; k < 5; ++k) {
    s.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.05 * k, 0.95 - 0.05 * k)});
    s.assignEstimate(k + 1, est[k], &kEstVar);
  }
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025), 0.8625, 1e-5);
  // Three quarters clay: the split goes above it (face 0.90), and its loam quarter fills the top
  // of its slab: the change is at 0.90 - 0.25 x 0.05.
  for (int q = 0; q < 5; ++q) mix[q] = 0.25 * loam[q] + 0.75 * clay[q];
  Strata t(config());
  for (int k = 0; k < 5; ++k) {
    t.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.05 * k, 0.95 - 0.05 * k)});
    t.assignEstimate(k + 1, est[k], &kEstVar);
  }
  EXPECT_NEAR(t.changeHeightAt(0.025, 0.025), 0.8875, 1e-5);
}

TEST(Strata, ANoisyEstimateMovesTheChangeLessThanSureOnes) {
  // Eight 5 cm slabs from 1.0: loam, loam, a wild estimate (80 kPa, but as uncertain as the
  // prior), loam, then clay; the soils differ in c only, the other properties at the prior's
  // means. Unweighted, the wild level (55 kPa after the prior) splits the loam: the change would
  // be at 0.90, two voxels high; weighted by precision it barely counts and the change is at 0.80.
  const SoilVector loam{10.2e3, 0.5, 10e3, 0.4, 17e3}, clay{49.8e3, 0.5, 10e3, 0.4, 17e3}, wild{80e3, 0.5, 10e3, 0.4, 17e3};
  const SoilVector sure{1e6, 1e-4, 4e5, 2e-4, 4e4}, unsure{1e8, 0.04, 4e7, 0.02, 4e6};
  const SoilVector* est[8] = {&loam, &loam, &wild, &loam, &clay, &clay, &clay, &clay};
  Strata s(config());
  for (int k = 0; k < 8; ++k) {
    s.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.05 * k, 0.95 - 0.05 * k)});
    s.assignEstimate(k + 1, est[k], k == 2 ? &unsure : &sure);
  }
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025), 0.80, 1e-5);
}

TEST(Strata, TheChangeIsSoughtOnlyInThePropertiesAsked) {
  // Eight 5 cm slabs: c changes below the fourth (loam to clay, 10 to 50 kPa); c_a, which the
  // estimates cannot tell (soil_pinn's case), jumps by more, in prior units, at the sixth. With
  // every property the split follows the c_a noise (0.70); asked for c alone it finds the soil's
  // change (0.80), which is what changes with the mask and nothing else.
  const SoilVector sure{1e6, 1e-4, 4e5, 2e-4, 4e4};
  std::vector<SoilVector> est(8, SoilVector{10e3, 0.5, 2e3, 0.4, 17e3});
  for (int k = 4; k < 8; ++k) est[static_cast<std::size_t>(k)][0] = 50e3;
  for (int k = 6; k < 8; ++k) est[static_cast<std::size_t>(k)][2] = 60e3;
  Strata s(config());
  for (int k = 0; k < 8; ++k) {
    s.applyCut(k + 1, {cell(0.025, 0.025, 1.0 - 0.05 * k, 0.95 - 0.05 * k)});
    s.assignEstimate(k + 1, &est[static_cast<std::size_t>(k)], &sure);
  }
  // (0.705: the sixth level's c reads as a tenth of the way to the deeper run: the mix.)
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025), 0.70, 0.01);
  strata::PropertyMask c_only{true, false, false, false, false};
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025, 1, 0.5, 0.0, nullptr, &c_only), 0.80, 1e-5);
  strata::PropertyMask ca_only{false, false, true, false, false};
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025, 1, 0.5, 0.0, nullptr, &ca_only), 0.70, 1e-5);
  // A property that does not change anywhere in the column: no change.
  strata::PropertyMask phi_only{false, true, false, false, false};
  EXPECT_TRUE(std::isnan(s.changeHeightAt(0.025, 0.025, 1, 0.5, 0.0, nullptr, &phi_only)));
}

TEST(Strata, NeighbouringColumnsPoolTheirEstimatesByLevel) {
  Strata s(config());
  const SoilVector loam{8e3, 0.5, 3e3, 0.35, 15e3}, clay{55e3, 0.5, 3e3, 0.35, 15e3};
  // Six one-voxel cuts per column; the soil changes below the fourth level. The centre column
  // has one wrong estimate (clay at level 2): alone its best split explains exactly half the
  // spread, with its two neighbours level 2 averages to 23.7 kPa and the split explains 93 %.
  const double cols[3][2] = {{0.025, 0.025}, {0.075, 0.025}, {0.025, 0.075}};
  long sweep = 0;
  for (int c = 0; c < 3; ++c)
    for (int k = 0; k < 6; ++k) {
      s.applyCut(++sweep, {cell(cols[c][0], cols[c][1], 1.0 - 0.05 * k, 0.95 - 0.05 * k)});
      const bool clay_here = k >= 4 || (c == 0 && k == 1);
      s.assignEstimate(sweep, clay_here ? &clay : &loam, &kEstVar);
    }
  EXPECT_TRUE(std::isnan(s.changeHeightAt(0.025, 0.025, 1, 0.6, 0.0)));
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025, 1, 0.6, 0.05), 0.8, 1e-6);
  EXPECT_NEAR(s.changeDepthAt(0.025, 0.025, 1, 0.6, 0.05), 0.2, 1e-6);
  // The radius reaches the 4-neighbours (0.05 m), not the diagonal (0.07 m): same answer at 0.06.
  EXPECT_NEAR(s.changeHeightAt(0.025, 0.025, 1, 0.6, 0.06), 0.8, 1e-6);
}

TEST(Strata, ExpectedCutAveragesTheNextDepthOfTheColumn) {
  Strata s(config());
  s.applyCut(1, {cell(0.025, 0.025, 1.0, 0.8)});
  s.assignEstimate(1, &kEst, &kEstVar);
  const SoilBelief e = s.expectedCut(0.025, 0.025, kNaN, 0.2);
  // Voxel centres 0.775, 0.725, 0.675, 0.625 below the surface at 0.8.
  double m = 0, sd = 0;
  for (double z : {0.775, 0.725, 0.675, 0.625}) {
    m += s.soilAt(0.025, 0.025, z).mean[0] / 4;
    sd += std::sqrt(s.soilAt(0.025, 0.025, z).var[0]) / 4;
  }
  EXPECT_NEAR(e.mean[0], m, 1e-6);
  EXPECT_NEAR(e.var[0], sd * sd, 1e-3);
  EXPECT_EQ(e.source, SoilSource::Inherited);
  // A column never cut: the prior.
  EXPECT_EQ(s.expectedCut(1.0, 1.0, kNaN, 0.2).source, SoilSource::Prior);
}

TEST(Strata, OneSweepsUniformSlabIsPrunedAndMemoryFollowsTheCutVolume) {
  Strata s(config());
  // A 0.4 x 0.4 m cell aligned with the octree: 8 x 8 columns x 8 voxels, one estimate.
  s.applyCut(1, {cell(0.2, 0.2, 0.4, 0.0, 0.4)});
  EXPECT_EQ(s.counters().voxels_removed, 512);
  const std::size_t unpruned = s.nodes();
  s.assignEstimate(1, &kEst, &kEstVar);
  EXPECT_LT(s.nodes(), unpruned / 8) << "a uniform slab collapses into a few parents";
  // The pruned slab still answers for every voxel.
  EXPECT_EQ(s.soilAt(0.01, 0.39, 0.01).source, SoilSource::Removed);
  EXPECT_EQ(s.soilAt(0.39, 0.01, 0.39).source, SoilSource::Removed);
  // Writing one voxel inside a pruned region expands it without losing the others.
  s.applyCut(2, {cell(0.025, 0.025, 0.0, -0.05)});
  s.assignEstimate(2, &kEstVar, &kEstVar);
  EXPECT_EQ(s.soilAt(0.39, 0.01, 0.39).source, SoilSource::Removed);
  EXPECT_FLOAT_EQ(static_cast<float>(s.soilAt(0.39, 0.01, 0.39).mean[0]), static_cast<float>(s.soilAt(0.01, 0.39, 0.01).mean[0]));
  // Cells outside the extent are counted, not stored.
  s.applyCut(3, {cell(50, 0, 1, 0.5)});
  EXPECT_EQ(s.counters().columns_outside, 1);
}

TEST(Strata, SaveAndLoadRoundTripEveryQuery) {
  Strata s(config());
  const SoilVector clay{55e3, 0.42, 20e3, 0.3, 19e3};
  for (int k = 0; k < 3; ++k) {
    s.applyCut(k + 1, {cell(0.3 * k, 0.1, 1.0 - 0.1 * k, 0.8 - 0.1 * k, 0.3)});
    s.assignEstimate(k + 1, k == 1 ? &clay : &kEst, &kEstVar);
  }
  s.applyCut(4, {cell(-1, -1, 0.5, 0.4, 0.2)});  // left pending: saved as predicted
  const std::string path = tmp("roundtrip.ot");
  s.save(path);
  const Strata r = Strata::load(path);
  EXPECT_EQ(r.nodes(), s.nodes());
  EXPECT_EQ(r.columns(), s.columns());
  long compared = 0;
  for (double x = -1.2; x < 1.0; x += 0.037)
    for (double z = 0.2; z < 1.1; z += 0.033) {
      const SoilBelief a = s.soilAt(x, 0.1, z), b = r.soilAt(x, 0.1, z);
      ASSERT_EQ(a.source, b.source) << x << " " << z;
      for (int q = 0; q < 5; ++q)
        if (std::isfinite(a.mean[q])) {
          EXPECT_EQ(a.mean[q], b.mean[q]);
          EXPECT_EQ(a.var[q], b.var[q]);
          ++compared;
        }
    }
  EXPECT_GT(compared, 1000);
  // Not ours, truncated: an input error naming the file.
  {
    std::ofstream o(tmp("other.ot"));
    o << "# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n";
  }
  try {
    Strata::load(tmp("other.ot"));
    ADD_FAILURE() << "loaded an OcTree";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("other.ot"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("TerramapStrataTree"), std::string::npos);
  }
  const auto size = std::filesystem::file_size(path);
  std::filesystem::resize_file(path, size - 10);
  EXPECT_THROW(Strata::load(path), InputError);
}

TEST(Strata, TheOctovisExportIsAColorOcTreeOctoMapReads) {
  Strata s(config());
  s.applyCut(1, {cell(0.2, 0.2, 0.4, 0.2, 0.4)});
  s.assignEstimate(1, &kEst, &kEstVar);
  const std::string path = tmp("octovis.ot");
  s.exportColorOt(path, 0, 0.1);
  std::unique_ptr<octomap::AbstractOcTree> t(octomap::AbstractOcTree::read(path));
  ASSERT_TRUE(t);
  ASSERT_EQ(t->getTreeType(), "ColorOcTree");
  auto* ct = dynamic_cast<octomap::ColorOcTree*>(t.get());
  ASSERT_NE(ct, nullptr);
  // 8 x 8 columns: 4 removed voxels and 2 predicted ones below the new surface each.
  long leafs = 0;
  for (auto it = ct->begin_leafs(); it != ct->end_leafs(); ++it)
    leafs += ct->isNodeOccupied(*it) ? (1L << (3 * (ct->getTreeDepth() - it.getDepth()))) : 0;
  EXPECT_EQ(leafs, 64 * 6);
  // Colours: viridis over c's range [0, 60 kPa] of the removed and the predicted soil.
  const io::Colormap viridis = io::Colormap::byName("viridis");
  for (double z : {0.3, 0.125}) {
    const auto* n = ct->search(0.2, 0.2, z);
    ASSERT_TRUE(n) << z;
    const io::Rgba want = viridis.at(s.soilAt(0.2, 0.2, z).mean[0] / 60e3);
    EXPECT_EQ(n->getColor(), octomap::ColorOcTreeNode::Color(want.r, want.g, want.b)) << z;
  }
}

TEST(OctomapStrataPlugin, CellCutsTakeTheFittedBankSurfaceAndTheSweptBottom) {
  SweepRecord r;
  r.resolution_m = 0.1;
  SweepMaskCell a, b, c;
  a.position = {0, 0};
  a.cut = true;
  a.sv_bottom_m = 0.4f;
  b.position = {0.1, 0};
  b.cut = false;
  c.position = {0.2, 0};
  c.cut = true;
  c.sv_bottom_m = 0.45f;
  r.mask = {a, b, c};
  SweepSlice s1, s2;
  s1.valid = true;
  s1.surface_z_m = 0.5;
  s1.cut_m = 0.12;
  s2.valid = false;
  s2.cut_m = 0.07;
  r.slices = {s1, s2};
  const auto cuts = cellCutsOf(r);
  ASSERT_EQ(cuts.size(), 2u);
  EXPECT_DOUBLE_EQ(cuts[0].old_surface_m, 0.5);
  EXPECT_FLOAT_EQ(static_cast<float>(cuts[0].new_surface_m), 0.4f);
  EXPECT_TRUE(std::isnan(cuts[1].old_surface_m));  // no fit: unknown (a pile is not bank)
  EXPECT_DOUBLE_EQ(cuts[1].cell_m, 0.1);
}

namespace {

// The plugin on a map with the layers it creates (as the host would) and a flat elevation.
struct Harness {
  LayeredMap map;
  Executor ex;
  RecordBus bus;
  PluginStats stats;
  ChangeTracker tracker;
  ProcessContext ctx;
  OctomapStrata plugin;
  explicit Harness(int threads = 1, std::map<std::string, ParamValue> params = {})
      : map(Geometry(0.1, Size(80, 80))), ex(threads), ctx(map, ex, bus, stats, "strata") {
    ctx.setTracker(&tracker);
    plugin.configure(makeParams("strata", plugin.schema(), params));
    for (const LayerSpec& l : plugin.layers())
      if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
    const LayerId h = map.addLayer("elevation", "m");
    for (int i = 0; i < 80; ++i)
      for (int j = 0; j < 80; ++j) map.set(h, Index(i, j), 1.0f);
    plugin.start(ctx);
  }
  float at(const std::string& layer, const Eigen::Vector2d& p) const {
    return map.at(map.layerId(layer), *map.geometry().indexAt(p));
  }
  // A sweep cutting a w x 0.3 m strip at x0 along +x from `from` to `to`.
  void sweep(long index, double x0, double from, double to) {
    SweepRecord r;
    r.sweep_index = index;
    r.resolution_m = 0.1;
    for (int i = 0; i < 3; ++i)
      for (int j = -5; j <= 5; ++j) {
        SweepMaskCell m;
        m.position = {x0 + 0.1 * i + 0.05, 0.1 * j + 0.05};
        m.cut = true;
        m.sv_bottom_m = static_cast<float>(to);
        r.mask.push_back(m);
        SweepSlice s;
        s.valid = true;
        s.surface_z_m = from;
        r.slices.push_back(s);
      }
    bus.publish<SweepRecord>(SweepRecord::kType, 0.0, std::make_shared<const SweepRecord>(r));
  }
  void estimate(long index, double x_end, double c_pa, bool valid = true) {
    SoilEstimateRecord e;
    e.sweep_index = index;
    e.T_map_blade1.translation() = Eigen::Vector3d(x_end, 0.0, 1.0);
    e.w_m = 1.1;
    e.mean = {c_pa, 0.5, 5e3, 0.35, 16e3};
    e.var_total = {4e6, 0.01, 1e6, 0.004, 1e6};
    e.valid = valid;
    bus.publish<SoilEstimateRecord>(SoilEstimateRecord::kType, 0.0, std::make_shared<const SoilEstimateRecord>(e));
  }
  void event() {
    plugin.process(ctx, Tick{});
    tracker.mark(map);  // as the host does after each call
  }
  // Four passes over the same strip, 0.1 m each, each sweep's estimate in the next event; the
  // soil turns from 8 to 55 kPa after two.
  void loamOverClay() {
    const double c[4] = {8e3, 8e3, 55e3, 55e3};
    for (int k = 0; k < 4; ++k) {
      sweep(k + 1, 0.0, 1.0 - 0.1 * k, 0.9 - 0.1 * k);
      event();
      estimate(k + 1, 0.3, c[k]);
      event();
    }
  }
};

}  // namespace

TEST(OctomapStrataPlugin, LayersShowTheNextCutTheRemovedDepthAndTheChange) {
  Harness h(1, {{"change_min_voxels", ParamValue{2L}}, {"change_radius_m", ParamValue{0.0}},
                {"change_interval_s", ParamValue{0.0}}, {"inherit", ParamValue{std::string("last")}}});
  h.loamOverClay();
  const Eigen::Vector2d p(0.15, 0.05);
  EXPECT_NEAR(h.at("strata_cut_m", p), 0.4f, 1e-5);
  EXPECT_NEAR(h.at("strata_change_depth_m", p), 0.2f, 1e-5);
  // The next cut: the clay below, inherited from the last estimate.
  EXPECT_NEAR(h.at("strata_next_c", p), h.plugin.model().expectedCut(p.x(), p.y(), kNaN, 0.2).mean[0], 1.0);
  EXPECT_GT(h.at("strata_next_c", p), 40e3f);
  EXPECT_TRUE(std::isnan(h.at("strata_next_c", {2.0, 2.0})));  // never cut, no surface layers
  // 4 sweeps x 33 cells of 0.1 m = 4 columns each x 2 voxels of 0.05 m.
  EXPECT_DOUBLE_EQ(h.stats.counters.at("voxels_estimated"), 4 * 33 * 4 * 2.0);
}

TEST(OctomapStrataPlugin, ChangePropertiesNameWhereTheChangeIsSought) {
  // loamOverClay's estimates differ in c only: sought in c the change is found, in phi there is none.
  const std::map<std::string, ParamValue> base{{"change_min_voxels", ParamValue{2L}},
                                               {"change_radius_m", ParamValue{0.0}},
                                               {"change_interval_s", ParamValue{0.0}}};
  auto with = [&](std::vector<std::string> props) {
    auto p = base;
    p["change_properties"] = ParamValue{std::move(props)};
    return p;
  };
  Harness c(1, with({"c"}));
  c.loamOverClay();
  EXPECT_NEAR(c.at("strata_change_depth_m", {0.15, 0.05}), 0.2f, 1e-5);
  Harness phi(1, with({"phi"}));
  phi.loamOverClay();
  EXPECT_TRUE(std::isnan(phi.at("strata_change_depth_m", {0.15, 0.05})));
  // A name that is not a property, or none at all, is refused naming the key.
  for (const auto& bad : {std::vector<std::string>{"cohesion"}, std::vector<std::string>{}}) {
    OctomapStrata p;
    try {
      p.configure(makeParams("strata", p.schema(), with(bad)));
      ADD_FAILURE() << "accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("change_properties"), std::string::npos) << e.what();
    }
  }
}

TEST(OctomapStrataPlugin, AChangeCellIsRecomputedWhenAColumnWithinItsPoolingRadiusIsCut) {
  // change_radius_m pools each cell's neighbours, so cutting a column changes the change layer of
  // the cells around it too, which no sweep touched.
  Harness h(1, {{"change_min_voxels", ParamValue{2L}}, {"change_radius_m", ParamValue{0.15}},
                {"change_interval_s", ParamValue{0.0}}});
  h.loamOverClay();  // the strip x 0..0.3: clay from 0.2 m down
  const Eigen::Vector2d edge(0.25, 0.05), inside(0.05, 0.05);
  const float before = h.at("strata_change_z_m", edge), inside_before = h.at("strata_change_z_m", inside);
  ASSERT_TRUE(std::isfinite(before));
  // The strip beside it (x 0.3..0.6), whose clay starts a pass higher.
  const double c[4] = {8e3, 55e3, 55e3, 55e3};
  for (int k = 0; k < 4; ++k) {
    h.sweep(10 + k, 0.3, 1.0 - 0.1 * k, 0.9 - 0.1 * k);
    h.event();
    h.estimate(10 + k, 0.6, c[k]);
    h.event();
  }
  const float after = h.at("strata_change_z_m", edge);
  EXPECT_NE(after, before);  // the neighbours' levels moved it
  EXPECT_FLOAT_EQ(after, static_cast<float>(h.plugin.model().changeHeightAt(edge.x(), edge.y(), 2, 0.3, 0.15)));
  // Beyond the radius from every new cut: as it was.
  EXPECT_EQ(h.at("strata_change_z_m", inside), inside_before);
}

TEST(OctomapStrataPlugin, AFirstFitAboveTheSurfaceTheMapHeldBeforeStartsFromThatSurface) {
  // The map knew the ground at 1.0 before any sweep (elevation, no loose layer); the first
  // sweep's fit says 1.08 (spoil pushed over the ground taken for bank). With the margin the
  // column starts at 1.0 (0.1 m cut to 0.9), without it at the fit (0.18 m).
  for (double margin : {0.05, -1.0}) {
    Harness h(1, {{"pristine_margin_m", ParamValue{margin}}});
    h.event();
    EXPECT_FLOAT_EQ(h.at("strata_pristine_m", {0.15, 0.05}), 1.0f);
    h.sweep(1, 0.0, 1.08, 0.9);
    h.event();
    EXPECT_NEAR(h.at("strata_cut_m", {0.15, 0.05}), margin < 0 ? 0.18f : 0.1f, 1e-5) << margin;
    EXPECT_EQ(h.stats.counters.count("first_surface_from_pristine"), margin < 0 ? 0u : 1u) << margin;
  }
  // A fit within the margin stands (1.02: 0.12 m cut).
  Harness w(1);
  w.event();
  w.sweep(1, 0.0, 1.02, 0.9);
  w.event();
  EXPECT_NEAR(w.at("strata_cut_m", {0.15, 0.05}), 0.12f, 1e-5);
  // A cell a sweep touched before the map knew it never takes the map's surface as pristine:
  // the surface seen later is the cut one.
  Harness u(1);
  const LayerId el = u.map.layerId("elevation");
  const Index cell = *u.map.geometry().indexAt({0.15, 0.05});
  u.map.set(el, cell, std::numeric_limits<float>::quiet_NaN());
  u.event();
  EXPECT_TRUE(std::isnan(u.at("strata_pristine_m", {0.15, 0.05})));
  u.sweep(1, 0.0, 1.0, 0.9);
  u.event();
  u.map.set(el, cell, 0.9f);
  u.event();
  EXPECT_EQ(u.at("strata_pristine_m", {0.15, 0.05}), -std::numeric_limits<float>::infinity());
  EXPECT_FLOAT_EQ(u.at("strata_pristine_m", {1.55, 1.05}), 1.0f);  // a cell no sweep touched
}

TEST(OctomapStrataPlugin, APristineTileBeyondASparseMapsBudgetIsDroppedCounted) {
  // A sparse map in tiles of 8 whose budget holds only the elevation tile already written: the
  // pristine surface there cannot be stored, nor the mark of a sweep that touches it; both are
  // counted and nothing throws.
  LayeredMap map(Geometry(0.1, Size(32, 32)), MapOptions{8, true});
  OctomapStrata plugin;
  plugin.configure(makeParams("strata", plugin.schema(), {}));
  for (const LayerSpec& l : plugin.layers())
    if (l.access == LayerAccess::Create) map.addLayer(l.name, l.unit, l.fill);
  const LayerId el = map.addLayer("elevation", "m");
  const Index cell = *map.geometry().indexAt({0.05, 0.05});
  map.set(el, cell, 1.0f);
  terramap::test::MemoryBudgetScope budget(static_cast<std::uint64_t>(map.allocatedTiles()) * map.tileBytes());
  Executor ex(1);
  RecordBus bus;
  PluginStats stats;
  ChangeTracker tracker;
  ProcessContext ctx(map, ex, bus, stats, "strata");
  ctx.setTracker(&tracker);
  plugin.start(ctx);
  plugin.process(ctx, Tick{});
  EXPECT_EQ(stats.dropped["pristine_tile_budget"], 1);
  EXPECT_TRUE(std::isnan(map.at(map.layerId("strata_pristine_m"), cell)));
  SweepRecord r;
  r.sweep_index = 1;
  r.resolution_m = 0.1;
  SweepMaskCell m;
  m.position = {0.05, 0.05};
  m.cut = false;  // touched (e.g. a deposit), not cut: nothing else of the strata's is written
  r.mask.push_back(m);
  bus.publish<SweepRecord>(SweepRecord::kType, 0.0, std::make_shared<const SweepRecord>(r));
  tracker.mark(map);
  EXPECT_NO_THROW(plugin.process(ctx, Tick{}));
  EXPECT_EQ(stats.dropped["pristine_tile_budget"], 2);
}

TEST(OctomapStrataPlugin, TheChangeLayerWaitsForItsIntervalOrTheEnd) {
  Harness h(1, {{"change_min_voxels", ParamValue{2L}}});  // every 5 s of event time (the stamps here stay 0)
  h.loamOverClay();
  const Eigen::Vector2d p(0.15, 0.05);
  EXPECT_TRUE(std::isnan(h.at("strata_change_depth_m", p)));  // computed once, at the first sweep
  EXPECT_NEAR(h.at("strata_cut_m", p), 0.4f, 1e-5);           // per event
  h.plugin.finish(h.ctx);
  EXPECT_NEAR(h.at("strata_change_depth_m", p), 0.2f, 1e-5);
}

TEST(OctomapStrataPlugin, LayersAreBitIdenticalAtOneAndTwoThreads) {
  Harness a(1, {{"change_interval_s", ParamValue{0.0}}}), b(2, {{"change_interval_s", ParamValue{0.0}}});
  for (Harness* h : {&a, &b})
    for (int k = 0; k < 6; ++k) {
      h->sweep(k + 1, 0.3 * (k % 3) - 1.0, 1.0 - 0.07 * (k / 3), 0.93 - 0.07 * (k / 3));
      h->event();
      h->estimate(k + 1, 0.3 * (k % 3) - 0.7, 10e3 + 7e3 * k, k != 4);
      h->event();
    }
  long cells = 0;
  for (const std::string& l : a.map.layerNames()) {
    const LayerId ia = a.map.layerId(l), ib = b.map.layerId(l);
    for (int i = 0; i < 80; ++i)
      for (int j = 0; j < 80; ++j) {
        const float x = a.map.at(ia, Index(i, j)), y = b.map.at(ib, Index(i, j));
        ASSERT_EQ(std::memcmp(&x, &y, sizeof(float)), 0) << l << " " << i << " " << j;
        cells += std::isfinite(x) ? 1 : 0;
      }
  }
  EXPECT_GT(cells, 1000);
}

TEST(OctomapStrataPlugin, FilesAreWrittenAtTheEnd) {
  const std::string ot = tmp("plugin_model.ot"), ov = tmp("plugin_octovis.ot"), png = tmp("plugin_section.png");
  for (const auto& f : {ot, ov, png}) std::filesystem::remove(f);
  Harness h(1, {{"save_path", ParamValue{ot}}, {"octovis_path", ParamValue{ov}}, {"section_png", ParamValue{png}},
                {"section_line_m", ParamValue{std::vector<double>{-0.5, 0.05, 0.8, 0.05}}}});
  h.sweep(1, 0.0, 1.0, 0.9);
  h.event();
  h.estimate(1, 0.3, 20e3);
  h.plugin.finish(h.ctx);
  EXPECT_TRUE(std::filesystem::exists(ot));
  EXPECT_TRUE(std::filesystem::exists(ov));
  EXPECT_GT(std::filesystem::file_size(png), 1000u);
  EXPECT_EQ(Strata::load(ot).soilAt(0.15, 0.05, 0.95).source, SoilSource::Removed);
}
