#pragma once
/// \file
/// The pipeline source `{type: sim, scenario: FILE, max_time_s: T}`: the simulator's event
/// streams, live, with the truth behind Source::truth (so `terramap run` reports the map's
/// error). It lives in terramap::eval, above the pipeline and the simulator, so that an
/// embedder linking only terramap::pipeline links neither the simulator nor HDF5.
/// The `terramap` CLI registers it at start-up; an embedder that wants it links terramap::eval
/// and calls registerSimSource() once before building a Source.
#include <terramap/core/export.hpp>

#include <string>
#include <utility>
#include <vector>

namespace terramap {
class Source;
}

namespace terramap::sim {

/// Registers source type "sim" with the pipeline's source registry. Idempotent and
/// thread-safe (the first call registers).
TERRAMAP_API void registerSimSource();

/// Names of the soil zones a `sim` source's truth layer `soil_zone` holds, by value (-1 = the
/// scenario's default soil), with family and relative density, for picture legends; empty for
/// any other source.
TERRAMAP_API std::vector<std::pair<int, std::string>> simSoilZoneNames(const Source& source);

}  // namespace terramap::sim
