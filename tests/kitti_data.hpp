#pragma once
// Where the tests find the KITTI frames, and the skip when they are absent. The frames are
// CC BY-NC-SA 3.0 (non-commercial), so they are not in the repository (data/README.md): one
// setting, the environment variable TERRAMAP_KITTI_DIR, names their folder; unset, it is
// ../shared/data/kitti_hdl64 beside the checkout (TERRAMAP_KITTI_DIR_DEFAULT, set by CMake).
// A test that needs them starts with TERRAMAP_SKIP_WITHOUT_KITTI(): without the files it is
// skipped (gtest's [  SKIPPED ], which CTest counts as skipped) and names the path it looked at.
#include <gtest/gtest.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace terramap::test {

/// The folder of the six frames and DERIVED_icp_relative_poses.txt.
inline std::string kittiDir() {
  const char* env = std::getenv("TERRAMAP_KITTI_DIR");
  if (env && *env) return std::filesystem::absolute(env).lexically_normal().string();
  return TERRAMAP_KITTI_DIR_DEFAULT;
}

inline std::string kittiPath(const std::string& file) { return kittiDir() + "/" + file; }

/// The first of the files the tests read that is missing, or "" when all are there.
inline std::string missingKittiFile() {
  for (int i = 0; i < 6; ++i) {
    char name[16];
    std::snprintf(name, sizeof name, "%06d.bin", i);
    if (!std::filesystem::is_regular_file(kittiPath(name))) return kittiPath(name);
  }
  const std::string poses = kittiPath("DERIVED_icp_relative_poses.txt");
  return std::filesystem::is_regular_file(poses) ? std::string() : poses;
}

}  // namespace terramap::test

/// Skips the calling test (from its body) when the KITTI frames are not there.
#define TERRAMAP_SKIP_WITHOUT_KITTI()                                                                \
  do {                                                                                               \
    const std::string terramap_missing_kitti_ = ::terramap::test::missingKittiFile();                \
    if (!terramap_missing_kitti_.empty())                                                            \
      GTEST_SKIP() << "KITTI frames not found: " << terramap_missing_kitti_                          \
                   << " is missing (set TERRAMAP_KITTI_DIR to their folder; data/README.md)";        \
  } while (0)
