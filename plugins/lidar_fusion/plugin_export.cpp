// The library's one export: the plugin record and factory (abi.hpp). Kept apart from
// the plugin's other sources so that lidar_fusion_kernels (tests, benchmarks) holds the classes
// without the C symbols.
#include <terramap/plugin/abi.hpp>

#include "lidar_fusion.hpp"

TERRAMAP_PLUGIN(terramap::plugins::LidarFusion, "lidar_fusion", "1.0.0",
                "LiDAR elevation fusion (elevation_mapping_cupy parity): gates, Mahalanobis outliers, "
                "per-tile deterministic fusion, visibility cleanup, upper bounds, drift compensation")
