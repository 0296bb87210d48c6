// libFuzzer target: pipeline YAML through terramap::parsePipelineString (the strict YAML
// reader over yaml-cpp, then the pipeline's structure and ranges). No plugin is loaded.
#include "fuzz_support.hpp"

#include <terramap/pipeline/pipeline_spec.hpp>

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  terramap::fuzz::setUp();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  terramap::fuzz::expectInputErrorsOnly([&] {
    terramap::parsePipelineString(text, "fuzz.yaml", "/nonexistent/terramap-fuzz");
  });
  return 0;
}
