// SequenceSource: real KITTI frames chained with the ICP relative poses, stamps from names /
// times / period, lazy reading, LAS origin folding, and configuration errors.
#include <terramap/io/readers.hpp>
#include <terramap/io/sequence.hpp>

#include "kitti_data.hpp"
#include "test_readers_util.hpp"

#include <cmath>
#include <filesystem>

namespace terramap::io {
namespace {

using test::dataPath;
using test::expectErrorWith;
using test::spit;
using test::spitText;
using test::TempDir;

const std::string kKittiDir = test::kittiDir();
const std::string kIcp = test::kittiPath("DERIVED_icp_relative_poses.txt");

std::string pcdWith(float x) {
  return "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1\nHEIGHT 1\nPOINTS 1\nDATA ascii\n" +
         std::to_string(x) + " 0 0\n";
}

TEST(Sequence, KittiFramesWithChainedIcpPosesAreEmittedLazilyInOrder) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  EXPECT_EQ(detectPoseFileFormat(kIcp), PoseFileFormat::Relative);
  const auto chain = chainRelativePoses(readRelativePoses(kIcp));
  SequenceSpec spec;
  spec.folder = kKittiDir;  // also holds .txt files, which the extension filter skips
  spec.period_s = 0.1;
  spec.start_stamp_s = 100.0;
  Eigen::Isometry3d T_map_world = Eigen::Isometry3d::Identity();
  T_map_world.translation() = Eigen::Vector3d(10, -5, 2);
  Eigen::Isometry3d T_body_sensor = Eigen::Isometry3d::Identity();
  T_body_sensor.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  spec.T_map_world = T_map_world;
  spec.T_body_sensor = T_body_sensor;
  SequenceSource seq(spec, loadSequencePoses(kIcp));
  ASSERT_EQ(seq.size(), 6u);
  EXPECT_EQ(std::filesystem::path(seq.files()[0]).filename(), "000000.bin");
  EXPECT_EQ(std::filesystem::path(seq.files()[5]).filename(), "000005.bin");
  const std::size_t counts[6] = {124668, 124605, 124478, 124167, 123969, 123924};
  for (std::size_t k = 0; k < 6; ++k) {
    EXPECT_EQ(seq.position(), k);
    auto pc = seq.next();
    ASSERT_TRUE(pc.has_value());
    EXPECT_EQ(pc->points.size(), counts[k]);
    EXPECT_DOUBLE_EQ(pc->stamp, 100.0 + 0.1 * static_cast<double>(k));
    EXPECT_EQ(pc->frame, "sensor");
    const Eigen::Isometry3d want = T_map_world * chain[k] * T_body_sensor;
    EXPECT_LT((pc->T_map_sensor.matrix() - want.matrix()).cwiseAbs().maxCoeff(), 1e-12) << k;
  }
  EXPECT_FALSE(seq.next().has_value());
  seq.rewind();
  EXPECT_EQ(seq.next()->points.size(), counts[0]);
}

TEST(Sequence, FrameIndexFromFileNamesPicksTheMatchingPose) {
  TERRAMAP_SKIP_WITHOUT_KITTI();
  TempDir dir("seq_idx");
  for (const char* n : {"000003.bin", "000005.bin"}) {
    std::filesystem::create_symlink(test::kittiPath(n), dir.path() / n);
  }
  const auto chain = chainRelativePoses(readRelativePoses(kIcp));
  SequenceSpec spec;
  spec.folder = dir.path().string();
  spec.frame_index = FrameIndex::FileNameNumber;
  SequenceSource seq(spec, SequencePoses::perFrame(chain, kIcp));
  ASSERT_EQ(seq.size(), 2u);
  EXPECT_TRUE(seq.pose(0).isApprox(chain[3], 1e-15));
  EXPECT_TRUE(seq.pose(1).isApprox(chain[5], 1e-15));
  EXPECT_DOUBLE_EQ(seq.stamp(1), 0.5);
  // Frame 7 has no pose: refused at construction, naming the file.
  std::filesystem::create_symlink(test::kittiPath("000000.bin"), dir.path() / "000007.bin");
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::perFrame(chain, kIcp)); },
                               {"6 frames", "frame 7", "000007.bin", kIcp});
}

TEST(Sequence, StampsFromNamesInNaturalOrderWithInterpolatedTrajectory) {
  TempDir dir("seq_tum");
  spitText(dir.file("10.pcd"), pcdWith(10));
  spitText(dir.file("2.pcd"), pcdWith(2));
  spitText(dir.file("1.PCD"), pcdWith(1));
  spitText(dir.file("notes.txt"), "ignored");
  const std::string tum = dir.file("traj.tum");
  spitText(tum, "0 0 0 0 0 0 0 1\n20 20 40 0 0 0 0 1\n");
  SequenceSpec spec;
  spec.folder = dir.path().string();
  spec.extensions = {"pcd"};  // normalised to ".pcd", case-insensitive match
  spec.stamps_from_file_names = true;
  SequenceSource seq(spec, loadSequencePoses(tum, parsePoseFileFormat("tum")));
  ASSERT_EQ(seq.size(), 3u);
  const double stamps[3] = {1, 2, 10};
  for (int k = 0; k < 3; ++k) {
    auto pc = seq.next();
    ASSERT_TRUE(pc);
    EXPECT_EQ(pc->stamp, stamps[k]);
    EXPECT_EQ(pc->points[0].x, static_cast<float>(stamps[k]));  // file k holds x = its name
    // Linear trajectory: translation (t, 2t, 0).
    EXPECT_NEAR(pc->T_map_sensor.translation().x(), stamps[k], 1e-12);
    EXPECT_NEAR(pc->T_map_sensor.translation().y(), 2 * stamps[k], 1e-12);
  }
  // A frame past the trajectory end is refused at construction with file and stamp.
  spitText(dir.file("25.pcd"), pcdWith(25));
  expectErrorWith([&] { SequenceSource(spec, loadSequencePoses(tum)); }, {"25.pcd", "stamp 25", "[0, 20]", tum});
  // Nanosecond stamps keep sub-microsecond precision through long double scaling.
  TempDir ns("seq_ns");
  spitText(ns.file("1317384512123456789.pcd"), pcdWith(0));
  SequenceSpec nspec;
  nspec.folder = ns.path().string();
  nspec.stamps_from_file_names = true;
  nspec.file_name_stamp_scale = 1e-9;
  EXPECT_NEAR(SequenceSource(nspec, SequencePoses::identity()).stamp(0), 1317384512.123456789, 1e-6);
}

TEST(Sequence, TimesFileStrideAndSelection) {
  TempDir dir("seq_times");
  for (int i = 0; i < 5; ++i) spitText(dir.file("f" + std::to_string(i) + ".pcd"), pcdWith(static_cast<float>(i)));
  spitText(dir.file("times.txt"), "0.5\n0.61\n0.72\n0.83\n0.94\n");
  SequenceSpec spec;
  spec.folder = dir.path().string();
  spec.times_file = dir.file("times.txt");
  spec.first = 1;
  spec.stride = 2;
  SequenceSource seq(spec, SequencePoses::identity());
  ASSERT_EQ(seq.size(), 2u);  // f1, f3
  EXPECT_EQ(seq.stamp(0), 0.61);
  EXPECT_EQ(seq.stamp(1), 0.83);
  EXPECT_EQ(seq.load(1).points[0].x, 3.f);
  spitText(dir.file("times.txt"), "0.5\n0.61\n");
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::identity()); }, {"times.txt", "2 stamps", "frame 3"});
}

TEST(Sequence, CloudsAreReadLazilyAndABadFileFailsOnlyWhenReached) {
  TempDir dir("seq_lazy");
  spitText(dir.file("a.pcd"), pcdWith(1));
  spit(dir.file("b.bin"), std::vector<unsigned char>(35, 0));  // 2 records + 3 bytes
  SequenceSpec spec;
  spec.folder = dir.path().string();
  SequenceSource seq(spec, SequencePoses::identity());  // does not read b.bin
  ASSERT_EQ(seq.size(), 2u);
  ASSERT_TRUE(seq.next());
  expectErrorWith([&] { seq.next(); }, {dir.file("b.bin"), "byte offset 32"});
  EXPECT_EQ(seq.position(), 1u);  // not advanced past the failing frame
}

TEST(Sequence, LasOriginIsFoldedIntoThePose) {
  TempDir dir("seq_las");
  const std::string las = dataPath("las_hexbin/hexbin-crop.las");
  std::filesystem::create_symlink(las, dir.path() / "tile.las");
  SequenceSpec spec;
  spec.folder = dir.path().string();
  SequenceSource seq(spec, SequencePoses::identity());
  const PointCloud pc = seq.load(0);
  LasReadOptions opt;
  opt.keep_double_positions = true;
  const LasCloud ref = readLas(las, opt);
  ASSERT_EQ(pc.points.size(), ref.size());
  for (std::size_t i : {std::size_t{0}, std::size_t{1234}, ref.size() - 1}) {
    const Eigen::Vector3d p = pc.T_map_sensor * Eigen::Vector3d(pc.points[i].x, pc.points[i].y, pc.points[i].z);
    EXPECT_LT((p - ref.positions[i]).cwiseAbs().maxCoeff(), 1e-4) << i;
  }
}

TEST(Sequence, ConfigurationErrors) {
  TempDir dir("seq_err");
  SequenceSpec spec;
  spec.folder = dir.file("missing");
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::identity()); }, {"missing", "does not exist"});
  spec.folder = dir.path().string();
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::identity()); }, {"no files", ".pcd, .ply, .bin, .las"});
  spec.extensions = {".lass"};
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::identity()); }, {"'.lass'", "did you mean '.las'"});
  spec.extensions = {};
  spitText(dir.file("frame_a.pcd"), pcdWith(0));
  spec.stamps_from_file_names = true;
  expectErrorWith([&] { SequenceSource(spec, SequencePoses::identity()); }, {"frame_a.pcd", "not a stamp"});
  spec.stamps_from_file_names = false;
  spec.period_s = 0;
  expectErrorWith<ConfigError>([&] { SequenceSource(spec, SequencePoses::identity()); }, {"period 0"});
  expectErrorWith<ConfigError>([] { parsePoseFileFormat("tumm"); }, {"'tumm'", "did you mean 'tum'"});
  spitText(dir.file("p.txt"), "# c\n1 2 3\n");
  expectErrorWith([&] { detectPoseFileFormat(dir.file("p.txt")); }, {dir.file("p.txt") + ":2:", "3 values"});
}

}  // namespace
}  // namespace terramap::io
