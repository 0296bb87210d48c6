// Linked into the deliberately mismatched plugins: records in the environment that the
// library's code ran (its static constructors), so a test can tell a refusal *before* loading
// from one after. A test that runs the `terramap` binary cannot see the child's environment:
// it names a file in TERRAMAP_TEST_MARK_FILE, which the constructor creates.
#include <cstdio>
#include <cstdlib>

namespace {
__attribute__((constructor)) void markLoaded() {
  setenv("TERRAMAP_TEST_LOADED_" TERRAMAP_TEST_MARK, "1", 1);
  if (const char* f = std::getenv("TERRAMAP_TEST_MARK_FILE"))
    if (FILE* out = std::fopen(f, "w")) std::fclose(out);
}
}  // namespace
