// fee_index: the FEE of a reference cut over the fused soil layers, with its variance.
#include "fee_index.hpp"

#include <terramap/soil/soil_parameters.hpp>

#include <algorithm>
#include <cmath>
#include <limits>

namespace terramap::plugins {

namespace {

constexpr double kPi = 3.14159265358979323846;

}  // namespace

ParamSchema FeeIndex::schema() const {
  const FeeIndexConfig d;
  return {
      param::real("alpha_rad", d.geometry.alpha_rad, -1.0, 1.0, "rad", "reference cut: surface slope"),
      param::real("rho_rad", d.geometry.rho_rad, 0.1, kPi - 0.1, "rad", "reference cut: rake angle"),
      param::real("d_m", d.geometry.d_m, 1e-3, 5.0, "m", "reference cut: depth"),
      param::real("w_m", d.geometry.w_m, 1e-3, 20.0, "m", "reference cut: width"),
      param::real("q_n", 0.0, 0.0, 1e7, "N", "reference cut: surcharge weight"),
      param::text("beta", "min", {"min", "nominal"},
                  "failure angle: beta* minimising N_gamma (min) or Rankine's pi/4 - phi/2 (nominal)"),
      param::text("component", "magnitude", {"magnitude", "horizontal"},
                  "index: |F| (Eq. 1's f) or F_x (the push along travel)"),
      param::text("soil_prefix", "soil_", {}, "soil layers read: <prefix>c, <prefix>phi, ... and their _var"),
      param::text("output", "fee_index", {}, "layers created: <output> and <output>_var"),
  };
}

void FeeIndex::configure(const Params& p) {
  cfg_.geometry.alpha_rad = p.getDouble("alpha_rad");
  cfg_.geometry.rho_rad = p.getDouble("rho_rad");
  cfg_.geometry.d_m = p.getDouble("d_m");
  cfg_.geometry.w_m = p.getDouble("w_m");
  cfg_.geometry.q_n = p.getDouble("q_n");
  cfg_.beta_min = p.getString("beta") == "min";
  cfg_.horizontal = p.getString("component") == "horizontal";
  prefix_ = p.getString("soil_prefix");
  output_ = p.getString("output");
  if (output_.empty()) p.fail("output", "the index layer needs a name");
}

std::vector<LayerSpec> FeeIndex::layers() const {
  std::vector<LayerSpec> out;
  for (const soil::SoilParamInfo& info : soil::kSoilParams) {
    const std::string l = prefix_ + info.name;
    out.push_back({l, LayerAccess::Read, "", std::numeric_limits<float>::quiet_NaN(), ""});
    out.push_back({l + "_var", LayerAccess::Read, "", std::numeric_limits<float>::quiet_NaN(), ""});
  }
  out.push_back({output_, LayerAccess::Create, "N", std::numeric_limits<float>::quiet_NaN(),
                 "FEE force of the reference cut on the soil layers " + prefix_ + "*; NaN = no soil belief or no valid FEE"});
  out.push_back({output_ + "_var", LayerAccess::Create, "N^2", std::numeric_limits<float>::quiet_NaN(),
                 "variance of " + output_ + " (J Sigma J^T over the soil layers' variances)"});
  return out;
}

// soil_bayes writes on these events (and at finish).
EventMask FeeIndex::events() const { return EventKind::Observation | EventKind::BladePose | EventKind::Pose; }

void FeeIndex::start(ProcessContext& ctx) {
  LayeredMap& map = ctx.map();
  for (std::size_t k = 0; k < mean_.size(); ++k) {
    mean_[k] = map.layerId(prefix_ + soil::kSoilParams[k].name);
    var_[k] = map.layerId(prefix_ + soil::kSoilParams[k].name + "_var");
    ctx.trackChanges(mean_[k]);
    ctx.trackChanges(var_[k]);
  }
  index_ = map.layerId(output_);
  index_var_ = map.layerId(output_ + "_var");
}

void FeeIndex::process(ProcessContext& ctx, const Event&) {
  std::vector<int> tiles;
  for (std::size_t k = 0; k < mean_.size(); ++k) {
    for (int t : ctx.changedTiles(mean_[k])) tiles.push_back(t);
    for (int t : ctx.changedTiles(var_[k])) tiles.push_back(t);
  }
  if (tiles.empty()) return;
  std::sort(tiles.begin(), tiles.end());
  tiles.erase(std::unique(tiles.begin(), tiles.end()), tiles.end());
  computeTiles(ctx, tiles);
}

void FeeIndex::finish(ProcessContext& ctx) { process(ctx, Tick{ctx.stamp()}); }

long FeeIndex::computeTiles(ProcessContext& ctx, const std::vector<int>& tiles) {
  LayeredMap& map = ctx.map();
  const int T = map.tileSize();
  std::vector<long> valid(tiles.size(), 0), invalid(tiles.size(), 0), budget(tiles.size(), 0);
  ctx.executor().forEach(static_cast<int>(tiles.size()), [&](int n) {
    const int t = tiles[static_cast<std::size_t>(n)];
    std::array<const float*, soil::kSoilParamCount> m{}, v{};
    for (std::size_t k = 0; k < m.size(); ++k) {
      m[k] = map.tileData(mean_[k], t);
      v[k] = map.tileData(var_[k], t);
    }
    const bool any_soil = m[0] != nullptr;
    // A sparse tile without soil needs no index either; one whose index exists is rewritten
    // (its soil may have been reset by a map move).
    if (!any_soil && !map.tileAllocated(index_, t)) return;
    if (!map.tryAllocateTile(t, {index_, index_var_})) {
      budget[static_cast<std::size_t>(n)] = 1;
      return;
    }
    float* out = map.mutableTileData(index_, t);
    float* out_var = map.mutableTileData(index_var_, t);
    const CellRect r = map.tileRect(t);
    for (int a = 0; a < r.rows; ++a)
      for (int b = 0; b < r.cols; ++b) {
        const std::size_t o = static_cast<std::size_t>(a) * static_cast<std::size_t>(T) + static_cast<std::size_t>(b);
        soil::SoilParamVector mv{}, vv{};
        bool finite = true;
        for (std::size_t k = 0; k < mv.size(); ++k) {
          mv[k] = m[k] ? m[k][o] : std::numeric_limits<double>::quiet_NaN();
          vv[k] = v[k] ? v[k][o] : std::numeric_limits<double>::quiet_NaN();
          finite = finite && std::isfinite(mv[k]) && std::isfinite(vv[k]);
        }
        FeeIndexValue f;
        if (finite) {
          f = feeIndexOf(soil::toFee(mv), soil::toFee(vv), cfg_);
          (f.validity == fee::Validity::Valid ? valid : invalid)[static_cast<std::size_t>(n)] += 1;
        }
        out[o] = static_cast<float>(f.index_n);
        out_var[o] = static_cast<float>(f.var_n2);
      }
  });
  long nv = 0, ni = 0, nb = 0;
  for (std::size_t k = 0; k < tiles.size(); ++k) {
    nv += valid[k];
    ni += invalid[k];
    nb += budget[k];
  }
  // Counted per computation (a cell recomputed twice counts twice): how much work was done and
  // how often a fused soil had no valid FEE for the reference cut.
  ctx.addCounter("tiles_computed", static_cast<double>(tiles.size() - static_cast<std::size_t>(nb)));
  ctx.addCounter("cells_computed", static_cast<double>(nv + ni));
  ctx.addCounter("cells_fee_invalid", static_cast<double>(ni));
  if (nb > 0) ctx.countDrop("tile_budget", nb);
  return nv;
}

}  // namespace terramap::plugins
