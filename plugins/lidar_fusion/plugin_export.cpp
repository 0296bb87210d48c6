// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// lidar_fusion.cpp so tests and benchmarks can compile the class without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "lidar_fusion.hpp"

TERRAMAP_PLUGIN(terramap::plugins::LidarFusion, "lidar_fusion", "1.0.0",
                "LiDAR elevation fusion (elevation_mapping_cupy parity): gates, Mahalanobis outliers, "
                "per-tile deterministic fusion, visibility cleanup, upper bounds, drift compensation")
