// A shared library built the way a careless embedder or plugin author might build one: default
// visibility, inline functions not hidden. Its globals hold the addresses of LayeredMap's
// matrix helpers, so their out-of-line copies are emitted here whatever the optimisation level;
// the test checks that they still are not exported (TERRAMAP_LOCAL), i.e. no other library or
// plugin can bind to this library's allocator through them.
#include <terramap/core/layered_map.hpp>

#define TEST_EXPORT __attribute__((visibility("default")))
TEST_EXPORT Eigen::MatrixXf (terramap::LayeredMap::*terramapTestToMatrix)(terramap::LayerId) const =
    &terramap::LayeredMap::toMatrix;
TEST_EXPORT void (terramap::LayeredMap::*terramapTestFromMatrix)(terramap::LayerId, const Eigen::MatrixXf&) =
    &terramap::LayeredMap::fromMatrix;

TEST_EXPORT long terramapTestMatrixUser(const terramap::LayeredMap& map, terramap::LayerId id) {
  return (map.*terramapTestToMatrix)(id).size();
}
