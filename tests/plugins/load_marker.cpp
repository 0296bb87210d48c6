// Linked into the deliberately mismatched plugins: records in the environment that the
// library's code ran (its static constructors), so a test can tell a refusal *before* loading
// from one after.
#include <cstdlib>

namespace {
__attribute__((constructor)) void markLoaded() { setenv("TERRAMAP_TEST_LOADED_" TERRAMAP_TEST_MARK, "1", 1); }
}  // namespace
