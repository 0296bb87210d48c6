// Blind mapping against the simulator's ground truth (paper §3.2, Fig. 10 style): the map
// starts from the true initial terrain, LiDAR is off, only the blade's poses update it
// (blade_sweep + soil_erosion). Checks that the blind map tracks the truth far better than the
// un-updated map, that the cut volume matches the truth's, and that the extracted FEE geometry
// matches the simulator's truth geometry of the cut.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <terramap/sim/simulator.hpp>

#include "blade_sweep.hpp"
#include "soil_erosion.hpp"

using namespace terramap;
using namespace terramap::plugins;

namespace {

const char* kScenario = R"(
version: 1
name: blind_strip
seed: 42
duration_s: 16
physics_hz: 240
observation_hz: 60
threads: 1
terrain:
  size_m: [16, 8]
  origin_m: [-3, -4]
  resolution_m: 0.02
  hills: {count: 4, amplitude_m: [-0.06, 0.08], sigma_m: [1.5, 3.0], seed: 7}
soil:
  default: {family: clay, relative_density: 0.10}
machines:
  - id: ctl1
    pose: {x_m: 0, y_m: 0, yaw_deg: 0}
    blade: {width_m: 1.85, height_m: 0.76, rake_deg: 80}
    controller:
      type: route
      start_m: [0, 0]
      heading_deg: 0
      length_m: 9
      spacing_m: 1.6
      passes: 1
      depth_m: 0.08
      speed_mps: 0.8
)";

double bilinear(const sim::TruthTerrain& t, double x, double y, bool initial) {
  const double fx = (x - t.originX()) / t.resolution(), fy = (y - t.originY()) / t.resolution();
  const int i = static_cast<int>(std::floor(fx)), j = static_cast<int>(std::floor(fy));
  if (!t.inside(i, j) || !t.inside(i + 1, j + 1)) return std::nan("");
  const double u = fx - i, v = fy - j;
  auto h = [&](int a, int b) { return initial ? t.initialHeight(a, b) : t.height(a, b); };
  return (1 - u) * (1 - v) * h(i, j) + u * (1 - v) * h(i + 1, j) + (1 - u) * v * h(i, j + 1) + u * v * h(i + 1, j + 1);
}

}  // namespace

TEST(SimBlind, BlindMapTracksTheTruthAndExtractsItsGeometry) {
  sim::Simulator sim(sim::parseScenario(kScenario, "blind_strip.yaml"));
  LayeredMap map(Geometry(0.05, Size(300, 140), Position(4.5, 0.0)));
  const LayerId h = map.addLayer("elevation", "m");
  const LayerId loose = map.addLayer("loose", "m", 0.0f);
  map.addLayer("height_sigma", "m");
  const Geometry& geo = map.geometry();
  Eigen::MatrixXf h0(geo.size().x(), geo.size().y());
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      h0(i, j) = static_cast<float>(bilinear(sim.truth(), p.x(), p.y(), true));
    }
  map.fromMatrix(h, h0);

  Executor ex(2);
  RecordBus bus;
  PluginStats bs, es;
  ProcessContext bctx(map, ex, bus, bs, "blade"), ectx(map, ex, bus, es, "erode");
  BladeSweep blade;
  blade.configure(makeParams("blade", blade.schema()));
  SoilErosion erosion;
  erosion.configure(makeParams("erode", erosion.schema()));
  blade.start(bctx);
  erosion.start(ectx);

  std::vector<double> err_d, err_alpha, err_w, dz_edge;
  // The largest realised error of the cutting edge the mapper was given (both ends of the edge,
  // so a roll or yaw error is in it): vertical and horizontal, over the whole route.
  double edge_err_z = 0, edge_err_xy = 0;
  long seen = 0;
  std::vector<Event> events;
  while (sim.next(events)) {
    for (const Event& e : events) {
      if (!std::holds_alternative<BladePose>(e)) continue;
      const BladePose& bp = std::get<BladePose>(e);
      for (double s : {-0.5, 0.5}) {
        const Eigen::Vector3d end(0, s * bp.geometry.width_m, 0);
        const Eigen::Vector3d err = bp.T_map_blade * end - sim.machineTruth(0).T_map_blade * end;
        edge_err_z = std::max(edge_err_z, std::abs(err.z()));
        edge_err_xy = std::max(edge_err_xy, err.head<2>().norm());
      }
      blade.process(bctx, e);
      erosion.process(ectx, e);
      const Record* r = bus.latest(SweepRecord::kType);
      if (!r || r->sequence == seen) continue;
      seen = r->sequence;
      const auto rec = std::static_pointer_cast<const SweepRecord>(r->payload);
      const sim::FeeTruth& ft = sim.machineTruth(0).fee;
      if (rec->fee_valid && ft.cutting_slices > 0 && std::isfinite(ft.depth_m) && !rec->steps.empty()) {
        err_d.push_back(rec->steps.back().d_m - ft.depth_m);
        // The realised vertical error of the edge the mapper was given (estimated - true) at
        // the sweep's end pose, the one its last step's depth is measured from.
        dz_edge.push_back(std::get<BladePose>(e).T_map_blade.translation().z() -
                          sim.machineTruth(0).T_map_blade.translation().z());
        err_alpha.push_back(rec->alpha_rad - ft.alpha_rad);
        err_w.push_back(rec->steps.back().w_m - ft.width_m);
      }
    }
    events.clear();
  }
  blade.finish(bctx);  // cuts the motion after the last sweep, as the engine does at the end
  erosion.finish(ectx);
  if (std::getenv("SIM_BLIND_DUMP")) {
    const auto& mt = sim.machineTruth(0);
    std::printf("final edge %.3f %.3f %.3f stalled %d raise %.3f\n", mt.T_map_blade.translation().x(),
                mt.T_map_blade.translation().y(), mt.T_map_blade.translation().z(), mt.stalled ? 1 : 0, mt.raise_offset_m);
    for (double x = -0.5; x < 9.5; x += 0.25) {
      const auto idx = geo.indexAt(Position(x, 0.01));
      if (!idx) continue;
      const float hm = map.at(h, *idx);
      std::printf("x %.2f map %.3f truth %.3f init %.3f\n", x, hm, bilinear(sim.truth(), x, 0.01, false),
                  bilinear(sim.truth(), x, 0.01, true));
    }
  }
  // Heights against the truth over the cells where either map changed, split along the route:
  // the first 4.25 m, where the truth keeps all pushed soil in front of the blade (the blind
  // model's assumption), and the rest, where the truth's surcharge has outgrown the 0.76 m blade
  // and spills back into the trench behind it, which the blind model does not represent
  // (documented limitation). The surface with loose soil is asserted on the first part; the bank
  // surface on the whole route (below).
  const Eigen::MatrixXf h1 = map.toMatrix(h);
  double se_blind[2] = {0, 0}, se_static[2] = {0, 0};
  long n[2] = {0, 0};
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      const double truth = bilinear(sim.truth(), p.x(), p.y(), false);
      if (!std::isfinite(truth) || !std::isfinite(h1(i, j))) continue;
      if (std::abs(truth - h0(i, j)) < 0.005 && std::abs(h1(i, j) - h0(i, j)) < 0.005) continue;
      const int part = p.x() < 4.25 ? 0 : 1;
      se_blind[part] += (h1(i, j) - truth) * (h1(i, j) - truth);
      se_static[part] += (h0(i, j) - truth) * (h0(i, j) - truth);
      ++n[part];
    }
  ASSERT_GT(n[0], 1000);
  double rmse_blind[2], rmse_static[2];
  for (int k = 0; k < 2; ++k) {
    rmse_blind[k] = std::sqrt(se_blind[k] / std::max(1L, n[k]));
    rmse_static[k] = std::sqrt(se_static[k] / std::max(1L, n[k]));
  }
  auto median = [](std::vector<double> v) {
    for (double& x : v) x = std::abs(x);
    std::sort(v.begin(), v.end());
    return v.empty() ? NAN : v[v.size() / 2];
  };
  std::printf("[ sim-blind ] first 4.25 m: %ld cells, rmse blind %.4f m, un-updated %.4f m | rest: %ld cells, "
              "rmse blind %.4f m, un-updated %.4f m | bank cut map %.3f m3, truth %.3f m3 | %zu sweeps vs truth: "
              "median |err| d %.4f m, alpha %.4f rad, w %.3f m\n",
              n[0], rmse_blind[0], rmse_static[0], n[1], rmse_blind[1], rmse_static[1], bs.counters["cut_bank_volume_m3"],
              sim.machineTruth(0).cut_bank_m3, err_d.size(), median(err_d), median(err_alpha), median(err_w));
  // The blind model's own error (the truth physics, a TERA-like wedge with spill, is not the
  // blind model) has regression guards set from measured values with margin, not derived
  // (2026-11-22, poses perfect: rmse 1.4 cm vs 7.1 cm un-updated, bank volume 1.544 vs 1.597 m3,
  // |d| error 2.3 cm, alpha 1e-4, w 0). The scenario has the realistic (rtk_imu) localisation,
  // whose error adds to it. The blind surface is the estimated cutting edge, so its vertical
  // error is the edge's: base z (white, bias, random walk over the run), the pitch error over
  // the 1.9 m from the base to the edge, and the lift cylinder's error over its lever. It is
  // independent of the model error, so the two add in quadrature (1-sigma of the edge error).
  const sim::MachineSpec& ms = sim.scenario().machines[0];
  const sim::LocalisationSpec& loc = ms.localisation;
  ASSERT_FALSE(loc.perfect);
  const sim::AxisError& z = loc.position[2];
  const sim::AxisError& pitch = loc.attitude[1];
  const double lever = sim::CompactTrackLoader::cylinderLever(0);
  const double T = sim.scenario().duration_s;
  const double var_z_white = z.white * z.white + std::pow(ms.blade_mount_x_m * pitch.white, 2) +
                             std::pow(loc.cylinder_white_m / lever, 2);
  const double var_z_slow = z.bias * z.bias + z.random_walk * z.random_walk * T / 2 +  // walk variance, mean over the run
                            std::pow(ms.blade_mount_x_m * pitch.bias, 2) + std::pow(loc.cylinder_bias_m / lever, 2);
  const double sigma_edge_z = std::sqrt(var_z_white + var_z_slow);  // 2.4 cm for rtk_imu
  EXPECT_LT(rmse_blind[0], std::hypot(0.3 * rmse_static[0], sigma_edge_z));
  EXPECT_NEAR(bs.counters["cut_bank_volume_m3"], sim.machineTruth(0).cut_bank_m3, 0.1 * sim.machineTruth(0).cut_bank_m3);
  ASSERT_GT(err_d.size(), 10u);
  // The extracted depth inherits the edge error: a blade estimated dz too high measures the cut
  // dz too shallow. With that realisation of the noise taken out (dz_edge, every sweep along the
  // whole route), what remains is the extraction's own error: the surface ahead is a weighted
  // line fit (weights exp(-C_x x), C_x = 3 /m), whose intercept on a surface of curvature k is
  // off by k / C_x^2; the scenario's hills (amplitude <= 0.08 m, sigma >= 1.5 m) curve by at
  // most A / sigma^2 = 0.036 /m each: 4 mm for one hill (the median), 16 mm were all four to
  // pile up at one place (the worst sweep), plus 1 mm for the truth's own fit of the surface
  // ahead (unweighted over 0.05-0.5 m).
  ASSERT_EQ(dz_edge.size(), err_d.size());
  std::vector<double> depth_residual(err_d.size());
  for (size_t k = 0; k < err_d.size(); ++k) depth_residual[k] = err_d[k] + dz_edge[k];
  const double k_hill = 0.08 / (1.5 * 1.5), cx2 = 3.0 * 3.0;
  EXPECT_LT(median(depth_residual), k_hill / cx2);
  double worst_residual = 0;
  for (double r : depth_residual) worst_residual = std::max(worst_residual, std::abs(r));
  EXPECT_LT(worst_residual, 4 * k_hill / cx2 + 0.001);
  std::printf("[ sim-blind ] depth error - realised edge error: median %.4f m, worst %.4f m (edge error median %.4f m)\n",
              median(depth_residual), worst_residual, median(dz_edge));
  // The bank (undisturbed) surface over the whole route, spill half included: the blind bank is
  // the envelope of the estimated edge's path, the truth's that of the true edge, so at a cell p
  // the two differ by the edge's vertical error plus the truth's bank moved by its horizontal
  // error: |blind(p) - truth(p)| <= e_z + max_{|q - p| <= e_xy + r_t} |truth(q) - truth(p)|,
  // with e_z, e_xy the largest realised edge errors above and r_t the truth's node spacing (its
  // bilinear surface ramps a cut's wall over one node). 1 mm for float storage and the 60 Hz
  // poses against the truth's 240 Hz steps (1.3 cm of travel, along a straight edge path). The
  // loose soil is left out: the truth spills it over the blade top into the trench, the blind
  // model keeps it in front of the blade (documented); its mass is checked by the cut volume.
  const Eigen::MatrixXf l1 = map.toMatrix(loose);
  const double r = edge_err_xy + sim.truth().resolution();
  long bank_cells[2] = {0, 0}, bank_over = 0;
  double bank_worst_ratio = 0, bank_se[2] = {0, 0};
  for (int i = 0; i < geo.size().x(); ++i)
    for (int j = 0; j < geo.size().y(); ++j) {
      const Position p = geo.positionOf(Index(i, j));
      const double truth = sim.truth().undisturbedAt(p.x(), p.y());
      const double blind = static_cast<double>(h1(i, j)) - l1(i, j);
      if (!std::isfinite(truth) || !std::isfinite(blind)) continue;
      if (std::abs(truth - h0(i, j)) < 0.005 && std::abs(blind - h0(i, j)) < 0.005) continue;
      double shift = 0;
      for (double dx = -r; dx <= r; dx += 0.005)
        for (double dy = -r; dy <= r; dy += 0.005) {
          if (dx * dx + dy * dy > r * r) continue;
          const double q = sim.truth().undisturbedAt(p.x() + dx, p.y() + dy);
          if (std::isfinite(q)) shift = std::max(shift, std::abs(q - truth));
        }
      const double bound = edge_err_z + shift + 0.001, e = std::abs(blind - truth);
      const int part = p.x() < 4.25 ? 0 : 1;
      ++bank_cells[part];
      bank_se[part] += e * e;
      bank_worst_ratio = std::max(bank_worst_ratio, e / bound);
      if (e > bound) ++bank_over;
    }
  std::printf("[ sim-blind ] bank surface: edge error max |dz| %.4f m, |dxy| %.4f m; %ld + %ld cells, rmse %.4f / %.4f m, "
              "worst error / bound %.3f, %ld over\n",
              edge_err_z, edge_err_xy, bank_cells[0], bank_cells[1], std::sqrt(bank_se[0] / std::max(1L, bank_cells[0])),
              std::sqrt(bank_se[1] / std::max(1L, bank_cells[1])), bank_worst_ratio, bank_over);
  EXPECT_GT(bank_cells[1], 1000);  // the spill half is in it
  EXPECT_EQ(bank_over, 0);
  EXPECT_LT(median(err_alpha), 0.05);
  EXPECT_LT(median(err_w), 0.15);
}
