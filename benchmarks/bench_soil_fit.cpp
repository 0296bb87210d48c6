// What soil_fit spends per blade sweep (plugins/soil_fit/README.md): the pooled fit of the
// windows around one sweep, for a machine crossing a soil boundary.
//
//   BM_SoilFitSweeps/threads:N: fitWindow for each of the 12 sweeps around a boundary between
//     a loose and a dense clay (Clay 10 % / 80 %, the Fig. 12 soils), in the order the plugin
//     publishes them, with the plugin's defaults: per sweep the centred window, the ones before
//     and after it (10 sweeps each, 10 rows per sweep) and the short ones before and after it
//     (5 sweeps), each from the plugin's starts (the middle of the ranges, the previous sweep's
//     fit after the first sweep, and the two corners of the c-phi valley): up to 20 bounded
//     Levenberg-Marquardt fits and the choice between the windows. N threads of an Executor run
//     the fits as its tasks (N = 1: serial); the estimates are the same for every N.
//     Rows are the estimator's own model at random depths 3-23 cm, rakes, surcharges and edge
//     motion with 300 N noise (the shape of the plugin's rows; their values change the
//     iteration counts, not the work per iteration).
//   Counters: sweeps_per_s (sweeps estimated per second of wall time), fits_per_sweep (the
//     fits run per sweep, WindowChoice::fits), iterations_per_sweep (Levenberg-Marquardt
//     iterations of the kept fit, mean), rows_per_window (rows in the chosen window, mean).
//
// soil_fit is a MODULE library (not linkable): this program links its kernel library,
// soil_fit_kernels, built with the module's flags.
#include "pooled_fit.hpp"
#include "soil_fit.hpp"

#include <terramap/core/parallel.hpp>
#include <terramap/soil/soil_table.hpp>

#include <benchmark/benchmark.h>

#include <random>

using namespace terramap;

namespace {

constexpr int kSweeps = 30, kRowsPerSweep = 10, kFirst = 9, kLast = 20, kShortSweeps = 5;

std::vector<soil::FitRow> sweepRows(const fee::Soil& s, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, 300.0);
  std::vector<soil::FitRow> rows;
  while (static_cast<int>(rows.size()) < kRowsPerSweep) {
    soil::FitRow r;
    r.geometry = fee::Geometry{0.05 * (u(rng) - 0.5), 1.25 + 0.2 * u(rng), 0.03 + 0.2 * u(rng), 1.85, 6000 * u(rng)};
    r.p_descending = u(rng) < 0.4 ? 1.0 : 0.0;
    Eigen::Vector2d f;
    if (!soil::modelForce(s, r, soil::PooledFitOptions{}, f)) continue;
    r.fx_n = f.x() + noise(rng);
    r.fz_n = f.y() + noise(rng);
    rows.push_back(r);
  }
  return rows;
}

void BM_SoilFitSweeps(benchmark::State& state) {
  const int threads = static_cast<int>(state.range(0));
  const fee::Soil loose = soil::soilProperties(soil::SoilFamily::Clay, 0.1).fee;
  const fee::Soil dense = soil::soilProperties(soil::SoilFamily::Clay, 0.8).fee;
  plugins::SweepWindow window = plugins::SweepWindow::keeping(9, 9, 2.0);
  for (int k = 0; k < kSweeps; ++k)
    window.add({0.2 * k, 0.0, 0.0}, sweepRows(k < kSweeps / 2 ? loose : dense, 500u + static_cast<unsigned>(k)));
  const Executor executor(threads);
  long iterations = 0, rows = 0, sweeps = 0, fits = 0;
  for (auto _ : state) {
    // The plugin's starts: the middle of the ranges (NaN) and, after the first sweep, the
    // machine's previous fit.
    soil::SoilParamVector middle;
    middle.fill(std::numeric_limits<double>::quiet_NaN());
    std::vector<soil::SoilParamVector> starts{middle};
    for (long seq = kFirst; seq <= kLast; ++seq) {
      const plugins::WindowChoice c =
          plugins::fitWindow(window, seq, 10, 5, 0.7, 10, starts, soil::PooledFitOptions{}, &executor, kShortSweeps);
      starts = {middle, c.fit.mean};
      const soil::SoilParamVector& last = c.fit.mean;
      iterations += c.fit.iterations;
      fits += c.fits;
      rows += static_cast<long>(c.rows);
      ++sweeps;
      benchmark::DoNotOptimize(last);
    }
  }
  state.counters["sweeps_per_s"] = benchmark::Counter(static_cast<double>(sweeps), benchmark::Counter::kIsRate);
  state.counters["fits_per_sweep"] = sweeps ? static_cast<double>(fits) / static_cast<double>(sweeps) : 0.0;
  state.counters["iterations_per_sweep"] = sweeps ? static_cast<double>(iterations) / static_cast<double>(sweeps) : 0.0;
  state.counters["rows_per_window"] = sweeps ? static_cast<double>(rows) / static_cast<double>(sweeps) : 0.0;
}
BENCHMARK(BM_SoilFitSweeps)->ArgName("threads")->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace

BENCHMARK_MAIN();
