// The blade_sweep plugin: parameters, update thresholds, per-machine pose history, report.
#include "blade_sweep.hpp"

#include <terramap/plugin/records/vertical_datum_record.hpp>

#include <cmath>
#include <cstdio>
#include <sstream>

namespace terramap::plugins {

namespace {
constexpr double kPi = 3.14159265358979323846;
/// Enough for a pile of a few m^3 at 5 cm cells (the soil moves a cell per sweep at most).
constexpr int kMaxPileSweeps = 4000;

void num(std::ostringstream& os, double v) {
  if (!std::isfinite(v)) {
    os << "null";
    return;
  }
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.9g", v);
  os << buf;
}

std::string jsonString(const std::string& s) {
  std::string out = "\"";
  for (char c : s) {
    if (c == '"' || c == '\\') {
      out += '\\';
      out += c;
    } else if (static_cast<unsigned char>(c) < 0x20) {
      char buf[8];
      std::snprintf(buf, sizeof buf, "\\u%04x", static_cast<unsigned>(static_cast<unsigned char>(c)));
      out += buf;
    } else {
      out += c;
    }
  }
  return out + "\"";
}

bool finitePose(const Eigen::Isometry3d& T) { return T.matrix().allFinite(); }

// Largest displacement of the two ends of the cutting edge between two poses.
double edgeTravel(const BladePose& a, const BladePose& b) {
  const auto ca = bladeCorners(a.T_map_blade, a.geometry);
  const auto cb = bladeCorners(b.T_map_blade, b.geometry);
  return std::max((cb[0] - ca[0]).norm(), (cb[1] - ca[1]).norm());
}

double rotationBetween(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::Quaterniond(a.linear()).angularDistance(Eigen::Quaterniond(b.linear()));
}
}  // namespace

std::string sweepRecordJson(const SweepRecord& r, bool with_steps) {
  std::ostringstream os;
  auto kv = [&](const char* k, double v) {
    os << ",\"" << k << "\":";
    num(os, v);
  };
  os << "{\"type\":\"" << SweepRecord::kType << "\",\"sweep_index\":" << r.sweep_index
     << ",\"machine_id\":" << jsonString(r.machine_id);
  kv("t0", r.t0);
  kv("t1", r.t1);
  os << ",\"edge0\":[";
  num(os, r.T_map_blade0.translation().x());
  os << ",";
  num(os, r.T_map_blade0.translation().y());
  os << ",";
  num(os, r.T_map_blade0.translation().z());
  os << "],\"edge1\":[";
  num(os, r.T_map_blade1.translation().x());
  os << ",";
  num(os, r.T_map_blade1.translation().y());
  os << ",";
  num(os, r.T_map_blade1.translation().z());
  os << "],\"t_hat\":[";
  num(os, r.t_hat.x());
  os << ",";
  num(os, r.t_hat.y());
  os << "],\"n_hat\":[";
  num(os, r.n_hat.x());
  os << ",";
  num(os, r.n_hat.y());
  os << "],\"m_hat\":[";
  num(os, r.m_hat.x());
  os << ",";
  num(os, r.m_hat.y());
  os << "]";
  kv("travel_m", r.travel_m);
  kv("rotation_rad", r.rotation_rad);
  kv("blade_angle_rad", r.blade_angle_rad);
  os << ",\"fee_valid\":" << (r.fee_valid ? "true" : "false");
  kv("alpha_rad", r.alpha_rad);
  kv("rho_rad", r.rho_rad);
  kv("d_m", r.d_m);
  kv("w_m", r.w_m);
  kv("vq0_m3", r.vq0_m3);
  kv("vq1_m3", r.vq1_m3);
  kv("q0_n", r.q0_n);
  kv("q1_n", r.q1_n);
  kv("var_alpha", r.var_alpha);
  kv("var_rho", r.var_rho);
  kv("var_d", r.var_d);
  kv("var_w", r.var_w);
  kv("var_vq", r.var_vq);
  kv("fit_residual_m", r.fit_residual_m);
  os << ",\"slices_valid\":" << r.slices_valid << ",\"slices_invalid\":" << r.slices_invalid;
  kv("cut_volume_m3", r.cut_volume_m3);
  kv("cut_bank_volume_m3", r.cut_bank_volume_m3);
  kv("deposit_volume_m3", r.deposit_volume_m3);
  kv("deposit_unknown_volume_m3", r.deposit_unknown_volume_m3);
  kv("lost_volume_m3", r.lost_volume_m3);
  os << ",\"cells_under_sv\":" << r.cells_under_sv << ",\"cells_cut\":" << r.cells_cut
     << ",\"cells_unknown_under_sv\":" << r.cells_unknown_under_sv << ",\"cells_deposit\":" << r.cells_deposit
     << ",\"cells_deposit_unknown\":" << r.cells_deposit_unknown << ",\"cells_lost\":" << r.cells_lost;
  if (with_steps) {
    os << ",\"steps\":[";
    for (size_t k = 0; k < r.steps.size(); ++k) {
      const SweepStep& s = r.steps[k];
      os << (k ? "," : "") << "{\"stamp\":";
      num(os, s.stamp);
      kv("tau", s.tau);
      kv("alpha_rad", s.alpha_rad);
      kv("rho_rad", s.rho_rad);
      kv("d_m", s.d_m);
      kv("w_m", s.w_m);
      kv("vq_m3", s.vq_m3);
      kv("q_n", s.q_n);
      kv("var_alpha", s.var_alpha);
      kv("var_rho", s.var_rho);
      kv("var_d", s.var_d);
      kv("var_w", s.var_w);
      kv("var_vq", s.var_vq);
      kv("var_q", s.var_q);
      os << "}";
    }
    os << "]";
  }
  os << "}";
  return os.str();
}

ParamSchema BladeSweep::schema() const {
  const SweepConfig d;
  return {
      param::real("min_translation_m", d.min_translation_m, 0.0, 100.0, "m",
                  "edge travel that triggers a swept-volume update (never below resolution*sqrt(2))"),
      param::real("min_rotation_rad", d.min_rotation_rad, 0.0, kPi, "rad",
                  "blade rotation since the last update that triggers one"),
      param::real("max_jump_m", d.max_jump_m, 1e-3, 1e4, "m",
                  "edge displacement between two consecutive poses treated as a teleport (history reset, no cut)"),
      param::integer("max_stations", d.max_stations, 2, 256, "poses of the history used as swept-volume mesh stations"),
      param::real("max_station_rotation_rad", d.max_station_rotation_rad, 1e-3, kPi, "rad",
                  "interpolated stations are inserted where consecutive ones rotate by more"),
      param::real("swell", d.swell, 1.0, 3.0, "1", "swell ratio s: loose thickness per undisturbed thickness"),
      param::real("deposit_normal_weight", d.deposit_normal_weight, 0.0, 1.0, "1",
                  "lambda_n: deposit direction m = lambda n + (1 - lambda) t"),
      param::real("fit_length_m", d.fit_length_m, 0.01, 20.0, "m", "surface samples ahead of each cut cell (FEE fit, V_Q)"),
      param::real("fit_distance_weight_per_m", d.fit_distance_weight, 0.0, 100.0, "1/m",
                  "C_x: line-fit weights exp(-C_x x)"),
      param::real("depth_weight_per_m", d.depth_weight, 0.0, 100.0, "1/m",
                  "C_d: slice-average weights exp(C_d d)"),
      param::real("unit_weight_n_m3", d.unit_weight_n_m3, 1.0, 1e5, "N/m^3",
                  "undisturbed unit weight gamma; loose gamma_l = gamma / swell gives Q = gamma_l V_Q"),
      param::real("sigma_sv_m", d.sigma_sv_m, 0.0, 10.0, "m", "1-sigma uncertainty of the blade height during a sweep"),
      param::real("min_cut_m", d.min_cut_m, 0.0, 1.0, "m", "elevation above the swept-volume bottom that counts as a cut"),
      param::boolean("surcharge_carried", d.surcharge_carried,
                     "Q from the soil the blade has cut since its pass began (up to the blade's capacity) instead of "
                     "the mapped loose soil ahead of the edge"),
      param::real("carried_repose_rad", d.carried_repose_rad, 0.05, 1.5, "rad",
                  "repose angle of the carried pile's face: the blade holds width x height^2 / (2 tan) of loose soil"),
      param::real("carried_overflow_share", d.carried_overflow_share, 0.0, 1.0, "1",
                  "surcharge_carried: share of the soil cut beyond the blade's capacity still counted in V_Q, with "
                  "the variance of a uniform between the capacity and all of it (0: capped at the capacity)"),
      param::boolean("loose_follows_elevation", d.loose_follows_elevation,
                     "the loose layer is re-read as elevation - loose_base at each update, so the blade pushes the "
                     "soil the sensors see (false: the bookkeeping alone)"),
      param::boolean("use_survey_datum", d.use_survey_datum,
                     "place the blade in a site survey's datum with the offset lidar_fusion estimated for its machine "
                     "(terramap.vertical_datum.v1) instead of the ground anchor, where there is one"),
      param::boolean("bank_reference", d.bank_reference,
                     "measure the FEE depth from the bank surface known before the pile covered it (layer "
                     "bank_surface), not from elevation - loose"),
      param::real("bank_reach_m", d.bank_reach_m, 0.5, 20.0, "m",
                  "bank_reference: cells up to this far ahead of the edge take their bank height"),
      param::boolean("report_steps", true, "write the per-step FEE values of every sweep to the run report"),
      param::boolean("ground_anchor", true, "shift blade heights by the map under the tracks minus the pose's contact plane"),
      param::real("track_length_m", 1.9, 0.1, 20.0, "m", "ground anchor: track contact length"),
      param::real("track_gauge_m", 1.6, 0.1, 20.0, "m", "ground anchor: distance between the track centrelines"),
      param::real("ground_anchor_tau_s", 10.0, 0.0, 1e4, "s", "ground anchor: low-pass time constant (0 = no filter)"),
      param::real("ground_anchor_max_m", 0.15, 0.0, 10.0, "m", "ground anchor: larger differences are ignored"),
      param::real("bucket_length_m", BucketConfig{}.length_m, 0.05, 10.0, "m",
                  "excavator bucket: pivot to cutting edge (default profile, README \"Buckets\")"),
      param::real("bucket_depth_m", BucketConfig{}.depth_m, 0.02, 10.0, "m", "excavator bucket: depth of its profile"),
      param::real("bucket_width_m", BucketConfig{}.width_m, 0.05, 10.0, "m", "excavator bucket: width"),
      param::real("pile_repose_rad", BucketConfig{}.pile_repose_rad, 0.05, 1.5, "rad",
                  "slope a dumped pile's loose soil settles to"),
      param::real("pile_reach_m", BucketConfig{}.pile_reach_m, 0.1, 20.0, "m", "how far a dumped pile may spread"),
      param::real("min_load_drop_kg", BucketConfig{}.min_load_drop_kg, 0.0, 1e5, "kg",
                  "a drop of the bucket's load below this is noise, not a pour"),
      param::integer("bucket_pose_window", BucketConfig{}.pose_window, 1, 99,
                     "bucket poses averaged (centred) before they sweep: the union of noisy stations widens the cut"),
      param::real("bucket_capacity_m3", 0.0, 0.0, 100.0, "m^3",
                  "loose soil the bucket holds (0 = the volume of its mesh); a full bucket cuts no more"),
  };
}

void BladeSweep::configure(const Params& p) {
  cfg_.min_translation_m = p.getDouble("min_translation_m");
  cfg_.min_rotation_rad = p.getDouble("min_rotation_rad");
  cfg_.max_jump_m = p.getDouble("max_jump_m");
  cfg_.max_stations = static_cast<int>(p.getInt("max_stations"));
  cfg_.max_station_rotation_rad = p.getDouble("max_station_rotation_rad");
  cfg_.swell = p.getDouble("swell");
  cfg_.deposit_normal_weight = p.getDouble("deposit_normal_weight");
  cfg_.fit_length_m = p.getDouble("fit_length_m");
  cfg_.fit_distance_weight = p.getDouble("fit_distance_weight_per_m");
  cfg_.depth_weight = p.getDouble("depth_weight_per_m");
  cfg_.unit_weight_n_m3 = p.getDouble("unit_weight_n_m3");
  cfg_.sigma_sv_m = p.getDouble("sigma_sv_m");
  cfg_.min_cut_m = p.getDouble("min_cut_m");
  cfg_.loose_follows_elevation = p.getBool("loose_follows_elevation");
  cfg_.bank_reference = p.getBool("bank_reference");
  cfg_.use_survey_datum = p.getBool("use_survey_datum");
  cfg_.bank_reach_m = p.getDouble("bank_reach_m");
  cfg_.surcharge_carried = p.getBool("surcharge_carried");
  cfg_.carried_repose_rad = p.getDouble("carried_repose_rad");
  cfg_.carried_overflow_share = p.getDouble("carried_overflow_share");
  report_steps_ = p.getBool("report_steps");
  anchor_cfg_.enabled = p.getBool("ground_anchor");
  anchor_cfg_.track_length_m = p.getDouble("track_length_m");
  anchor_cfg_.track_gauge_m = p.getDouble("track_gauge_m");
  anchor_cfg_.tau_s = p.getDouble("ground_anchor_tau_s");
  anchor_cfg_.max_m = p.getDouble("ground_anchor_max_m");
  bucket_cfg_.length_m = p.getDouble("bucket_length_m");
  bucket_cfg_.depth_m = p.getDouble("bucket_depth_m");
  bucket_cfg_.width_m = p.getDouble("bucket_width_m");
  bucket_cfg_.pile_repose_rad = p.getDouble("pile_repose_rad");
  bucket_cfg_.pile_reach_m = p.getDouble("pile_reach_m");
  bucket_cfg_.min_load_drop_kg = p.getDouble("min_load_drop_kg");
  bucket_cfg_.capacity_m3 = p.getDouble("bucket_capacity_m3");
  bucket_cfg_.pose_window = static_cast<int>(p.getInt("bucket_pose_window"));
  if (bucket_cfg_.pose_window % 2 == 0) p.fail("bucket_pose_window", "must be odd (a centred window)");
  tool_ = bucket_cfg_.mesh();
  if (cfg_.max_jump_m <= cfg_.min_translation_m)
    p.fail("max_jump_m", "must be larger than min_translation_m (" + std::to_string(cfg_.min_translation_m) + ")");
}

std::vector<LayerSpec> BladeSweep::layers() const {
  std::vector<LayerSpec> out = {
      {"elevation", LayerAccess::Write, "", std::numeric_limits<float>::quiet_NaN(), ""},
      {"loose", LayerAccess::Create, "m", 0.0f,
       "thickness of loose (swelled, disturbed) soil on top of the elevation; may be > 0 where elevation is NaN "
       "(blade deposits on unseen ground)"},
      {"height_sigma", LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
       "1-sigma of the elevation changes made by the blade and erosion; NaN = never changed by them"},
  };
  if (cfg_.bank_reference)
    out.push_back({"bank_surface", LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
                   "map z of the bank (undisturbed) surface as the map knew it before loose soil covered it, kept "
                   "by blade_sweep for the FEE depth; NaN = not yet ahead of a blade"});
  if (cfg_.loose_follows_elevation)
    out.push_back({"loose_base", LayerAccess::Create, "m", std::numeric_limits<float>::quiet_NaN(),
                   "map z of the undisturbed surface under the loose soil, kept by blade_sweep (loose = "
                   "elevation - loose_base where both are known); NaN = not yet under a blade's update"});
  return out;
}

SweepLayers SweepLayers::of(const LayeredMap& map) {
  SweepLayers ids;
  ids.elevation = map.layerId("elevation");
  ids.loose = map.layerId("loose");
  ids.sigma = map.layerId("height_sigma");
  auto optional = [&](const char* name) { return map.hasLayer(name) ? map.layerId(name) : LayerId(-1); };
  ids.variance = optional("variance");
  ids.is_valid = optional("is_valid");
  ids.upper_bound = optional("upper_bound");
  ids.is_upper_bound = optional("is_upper_bound");
  ids.base = optional("loose_base");
  ids.bank = optional("bank_surface");
  return ids;
}

void BladeSweep::start(ProcessContext& ctx) {
  ids_ = SweepLayers::of(ctx.map());
  const double res = ctx.map().geometry().resolution();
  if (cfg_.fit_length_m < 2.0 * res) {
    std::ostringstream os;
    os << ctx.name() << ": fit_length_m (" << cfg_.fit_length_m << " m) must cover at least 3 map cells (resolution "
       << res << " m)";
    throw ConfigError(os.str());
  }
}

void BladeSweep::anchorToGround(ProcessContext& ctx, const Pose& pose) {
  if (!anchor_cfg_.enabled || !finitePose(pose.T_map_base) || !std::isfinite(pose.stamp)) return;
  // "base" (one machine) or "<id>/base".
  std::string id;
  if (pose.frame != "base") {
    const auto slash = pose.frame.rfind("/base");
    if (slash == std::string::npos || slash + 5 != pose.frame.size()) return;
    id = pose.frame.substr(0, slash);
  }
  const LayeredMap& map = ctx.map();
  const Geometry& geo = map.geometry();
  // Each track half rests on its highest point (5 samples along it, as the half is rigid): the
  // map's height there minus the height of the same point on the pose's contact plane.
  const double L = anchor_cfg_.track_length_m, B = anchor_cfg_.track_gauge_m;
  double sum = 0;
  for (int fr = 0; fr < 2; ++fr)
    for (int lr = 0; lr < 2; ++lr) {
      double best_map = -INFINITY, plane_at_best = 0;
      for (int m = 0; m < 5; ++m) {
        const double lx = (fr == 0 ? 1.0 : -1.0) * 0.5 * L * (m + 0.5) / 5.0, ly = (lr == 0 ? 0.5 : -0.5) * B;
        const Eigen::Vector3d p = pose.T_map_base * Eigen::Vector3d(lx, ly, 0.0);
        const auto idx = geo.indexAt(p.head<2>());
        if (!idx) return;
        const float h = map.at(ids_.elevation, *idx);
        if (std::isnan(h)) return;  // unknown ground under a track: no anchor from this pose
        if (h > best_map) {
          best_map = h;
          plane_at_best = p.z();
        }
      }
      sum += best_map - plane_at_best;
    }
  const double diff = 0.25 * sum;
  if (!(std::abs(diff) <= anchor_cfg_.max_m)) {
    ctx.addCounter("ground_anchor_rejected", 1);
    return;
  }
  Anchor& a = anchors_[id];
  if (!a.init) {
    a.offset_m = diff;
    a.init = true;
  } else {
    const double dt = std::max(0.0, pose.stamp - a.stamp);
    const double k = anchor_cfg_.tau_s > 0 ? 1.0 - std::exp(-dt / anchor_cfg_.tau_s) : 1.0;
    a.offset_m += k * (diff - a.offset_m);
  }
  a.stamp = pose.stamp;
  ctx.addCounter("ground_anchor_updates", 1);
}

void BladeSweep::process(ProcessContext& ctx, const Event& event) {
  if (const auto* pose = std::get_if<Pose>(&event)) {
    anchorToGround(ctx, *pose);
    return;
  }
  if (const auto* js = std::get_if<JointState>(&event)) {
    processJointState(ctx, *js);
    return;
  }
  const auto* bp_in = std::get_if<BladePose>(&event);
  if (!bp_in) return;
  // The blade pose in the survey's datum (lidar_fusion's survey_datum: the same offset the
  // machine's clouds were fused with), else shifted by its machine's ground anchor (the id's
  // own, else the "base" one).
  BladePose anchored;
  const BladePose* bp = bp_in;
  if (const double dz = heightCorrection(ctx, bp_in->machine_id); dz != 0.0) {
    anchored = *bp_in;
    anchored.T_map_blade.translation().z() += dz;
    bp = &anchored;
  }
  const BladeGeometry& g = bp->geometry;
  if (!(g.width_m > 0) || !(g.height_m >= 0) || !std::isfinite(g.width_m) || !std::isfinite(g.height_m)) {
    std::ostringstream os;
    os << ctx.name() << ": blade pose at stamp " << bp->stamp << " (machine '" << bp->machine_id
       << "') has an invalid blade geometry: width_m = " << g.width_m << ", height_m = " << g.height_m
       << " (need width_m > 0, height_m >= 0)";
    throw InputError(os.str());
  }
  if (!finitePose(bp->T_map_blade) || !std::isfinite(bp->stamp)) {
    ctx.countDrop("non_finite_pose");
    return;
  }
  MachineState& st = machines_[bp->machine_id];
  if (!st.history.empty()) {
    const BladePose& last = st.history.back();
    if (bp->stamp < last.stamp) {
      ctx.countDrop("stamp_out_of_order");
      return;
    }
    const BladePose& first = st.history.front();
    if (first.geometry.width_m != g.width_m || first.geometry.height_m != g.height_m) {
      ctx.addCounter("geometry_changes", 1);  // a new tool: start a new sweep from here
      st.history.clear();
    } else if ((bp->T_map_blade.translation() - last.T_map_blade.translation()).norm() > cfg_.max_jump_m) {
      ctx.addCounter("pose_jumps", 1);
      st.history.clear();
    }
  }
  st.history.push_back(*bp);
  if (st.history.size() < 2) return;

  const double min_t = std::max(cfg_.min_translation_m, ctx.map().geometry().resolution() * std::sqrt(2.0));
  const BladePose& first = st.history.front();
  const bool moved = edgeTravel(first, *bp) > min_t;
  const bool turned = rotationBetween(first.T_map_blade, bp->T_map_blade) > cfg_.min_rotation_rad;
  if (!moved && !turned) {
    // A stalled blade keeps sending poses: thin the history (keep both ends) so it stays bounded.
    if (st.history.size() > 1024) {
      std::vector<BladePose> thin;
      for (size_t k = 0; k < st.history.size(); k += 2) thin.push_back(st.history[k]);
      if (thin.back().stamp != st.history.back().stamp) thin.push_back(st.history.back());
      st.history.swap(thin);
    }
    return;
  }

  sweepHistory(ctx, st, bp->machine_id, bp->stamp);
}

void BladeSweep::sweepHistory(ProcessContext& ctx, MachineState& st, const std::string& machine_id, double stamp) {
  auto rec = runSweep(ctx.map(), ids_, cfg_, st.history, ctx.executor(), &st.pile);
  if (!rec) {
    // No room in a sparse map's memory budget for the tiles under the sweep: it is dropped,
    // and the next sweep starts from this pose.
    ctx.countDrop("tile_budget");
    const BladePose last = st.history.back();
    st.history.clear();
    st.history.push_back(last);
    return;
  }
  rec->sweep_index = ++sweeps_;
  rec->machine_id = machine_id;
  ctx.addCounter("sweeps", 1);
  ctx.addCounter("cells_cut", static_cast<double>(rec->cells_cut));
  ctx.addCounter("cut_volume_m3", rec->cut_volume_m3);
  ctx.addCounter("cut_bank_volume_m3", rec->cut_bank_volume_m3);
  ctx.addCounter("deposit_volume_m3", rec->deposit_volume_m3);
  ctx.addCounter("deposit_unknown_volume_m3", rec->deposit_unknown_volume_m3);
  ctx.addCounter("lost_volume_m3", rec->lost_volume_m3);
  if (rec->cells_lost > 0) ctx.countDrop("deposit_off_map", rec->cells_lost);
  ctx.reportRecord(sweepRecordJson(*rec, report_steps_));
  ctx.records().publish<SweepRecord>(SweepRecord::kType, stamp, rec);
  // T1 of this sweep is T0 of the next.
  const BladePose last = st.history.back();
  st.history.clear();
  st.history.push_back(last);
}

double BladeSweep::heightCorrection(ProcessContext& ctx, const std::string& machine_id) {
  if (cfg_.use_survey_datum) {
    if (const auto datum = ctx.records().latestAs<VerticalDatumRecord>(VerticalDatumRecord::kType)) {
      const auto it = datum->machines.find(machine_id);
      if (it != datum->machines.end()) {
        datum_machines_.insert(machine_id);
        return -it->second.offset_m;
      }
    }
  }
  return anchorOffset(machine_id);
}

double BladeSweep::anchorOffset(const std::string& machine_id) const {
  if (!anchor_cfg_.enabled) return 0.0;
  auto it = anchors_.find(machine_id);
  if (it == anchors_.end()) it = anchors_.find("");  // one machine: the Pose frame "base"
  return it != anchors_.end() && it->second.init ? it->second.offset_m : 0.0;
}

void BladeSweep::processJointState(ProcessContext& ctx, const JointState& js) {
  if (!finitePose(js.T_map_bucket) || !std::isfinite(js.stamp)) {
    ctx.countDrop("non_finite_pose");
    return;
  }
  Eigen::Isometry3d T = js.T_map_bucket;
  T.translation().z() += heightCorrection(ctx, js.machine_id);  // the same height correction as the machine's blade
  BucketState& st = buckets_[js.machine_id];
  if (!st.raw.empty() && (T.translation() - st.raw.back().translation()).norm() > cfg_.max_jump_m) {
    ctx.addCounter("pose_jumps", 1);
    advanceBucket(ctx, st, true);
    st.poses.clear();
  }
  st.raw.push_back(T);
  advanceBucket(ctx, st, false);
  // The machine weighs its bucket: a drop beyond the threshold is a pour; drops below it
  // accumulate until they pass it; a rising load is the new reference.
  const double load = js.bucket_load_kg;
  if (std::isfinite(load) && std::isfinite(st.last_load_kg) && st.last_load_kg - load > bucket_cfg_.min_load_drop_kg)
    pourShare(ctx, st, T * tool_.lip, load);
  else if (st.pile_pending)
    settleBucketPile(ctx, st);  // the pour has ended
  if (std::isfinite(load) && !(load <= st.last_load_kg)) st.last_load_kg = load;
}

void BladeSweep::pourShare(ProcessContext& ctx, BucketState& st, const Eigen::Vector3d& lip, double load_kg) {
  // What the bucket lost, as a share of what it held, leaves the soil the map has it carry, over
  // the lip, after the bucket's motion so far has cut.
  sweepBucket(ctx, st);
  const double bank = st.carried_bank_m3 * std::clamp((st.last_load_kg - load_kg) / st.last_load_kg, 0.0, 1.0);
  // A few sweeps per pour keep the pile from standing as a column while it grows; it settles
  // fully once the pour ends.
  const BucketResult r = pourBucket(ctx.map(), ids_, cfg_, bucket_cfg_, lip, bank, 8);
  if (r.dropped) {
    ctx.countDrop("tile_budget");
    return;
  }
  st.carried_bank_m3 -= bank;
  st.last_load_kg = load_kg;
  st.pile_pending = true;
  st.pile_at = lip;
  ctx.addCounter("bucket_pours", 1);
  ctx.addCounter("bucket_poured_bank_m3", r.deposit_bank_m3);
  ctx.addCounter("deposit_unknown_volume_m3", r.unknown_bank_m3 * cfg_.swell);
  ctx.addCounter("lost_volume_m3", r.lost_bank_m3 * cfg_.swell);
  if (r.lost_bank_m3 > 0) ctx.countDrop("deposit_off_map");
}

void BladeSweep::settleBucketPile(ProcessContext& ctx, BucketState& st) {
  const int sweeps = settlePile(ctx.map(), ids_, bucket_cfg_, st.pile_at, kMaxPileSweeps);
  ctx.addCounter("bucket_pile_settle_sweeps", sweeps);
  if (sweeps == kMaxPileSweeps) ctx.addCounter("bucket_pile_unsettled", 1);
  st.pile_pending = false;
}

void BladeSweep::advanceBucket(ProcessContext& ctx, BucketState& st, bool flush) {
  const std::size_t win = static_cast<std::size_t>(std::max(1, bucket_cfg_.pose_window)), half = win / 2;
  auto smoothed = [&](std::size_t centre) {
    // The mean over the window around `centre` (shrunk to stay symmetric inside st.raw):
    // translations averaged, rotations by the normalised sum of sign-aligned quaternions.
    const std::size_t h = std::min({half, centre, st.raw.size() - 1 - centre});
    Eigen::Vector3d t = Eigen::Vector3d::Zero();
    const Eigen::Quaterniond q0(st.raw[centre].linear());
    Eigen::Vector4d qs = Eigen::Vector4d::Zero();
    for (std::size_t k = centre - h; k <= centre + h; ++k) {
      t += st.raw[k].translation();
      Eigen::Quaterniond q(st.raw[k].linear());
      if (q.dot(q0) < 0) q.coeffs() = -q.coeffs();
      qs += q.coeffs();
    }
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    T.translation() = t / static_cast<double>(2 * h + 1);
    T.linear() = Eigen::Quaterniond(qs.normalized()).toRotationMatrix();
    return T;
  };
  const double min_t = std::max(cfg_.min_translation_m, ctx.map().geometry().resolution() * std::sqrt(2.0));
  auto append = [&](const Eigen::Isometry3d& T) {
    st.poses.push_back(T);
    if (st.poses.size() < 2) return;
    const Eigen::Isometry3d& first = st.poses.front();
    const bool moved = ((T * tool_.lip) - (first * tool_.lip)).norm() > min_t;
    if (moved || rotationBetween(first, T) > cfg_.min_rotation_rad) sweepBucket(ctx, st);
  };
  if (flush) {
    // The poses not smoothed yet (the last `half`, or all when fewer arrived), their windows
    // shrinking at the end.
    for (std::size_t c = st.raw.size() > half ? st.raw.size() - half : 0; c < st.raw.size(); ++c) append(smoothed(c));
    st.raw.clear();
    return;
  }
  // One smoothed pose per received pose: the one `half` poses back (the first ones with the
  // part of their window that exists, symmetric).
  if (st.raw.size() > half) append(smoothed(st.raw.size() - 1 - half));
  if (st.raw.size() > win) st.raw.erase(st.raw.begin());
}

void BladeSweep::sweepBucket(ProcessContext& ctx, BucketState& st) {
  if (st.poses.size() < 2) return;
  const double capacity = bucket_cfg_.capacity_m3 > 0 ? bucket_cfg_.capacity_m3 : tool_.volume_m3;
  const double room = std::max(0.0, capacity / cfg_.swell - st.carried_bank_m3);
  const BucketResult r = runBucketSweep(ctx.map(), ids_, cfg_, tool_, st.poses, room, ctx.executor());
  if (r.dropped) {
    ctx.countDrop("tile_budget");
  } else {
    st.carried_bank_m3 += r.cut_bank_m3;
    ctx.addCounter("bucket_sweeps", 1);
    ctx.addCounter("bucket_cut_bank_m3", r.cut_bank_m3);
    ctx.addCounter("cells_cut", static_cast<double>(r.cells_cut));
    if (r.cells_unknown > 0) ctx.countDrop("bucket_over_unknown", r.cells_unknown);
  }
  const Eigen::Isometry3d last = st.poses.back();
  st.poses.clear();
  st.poses.push_back(last);
}

void BladeSweep::finish(ProcessContext& ctx) {
  for (auto& [id, st] : buckets_) {
    advanceBucket(ctx, st, true);
    sweepBucket(ctx, st);
    if (st.pile_pending) settleBucketPile(ctx, st);
    // Soil still in a bucket at the end is neither in the map nor lost: reported.
    ctx.addCounter("bucket_carried_bank_m3", st.carried_bank_m3);
  }
  buckets_.clear();
  // The blade's last motion is shorter than a sweep's minimum travel (it stopped, or the run
  // ended mid-motion): cut it now, or the soil it moved would never reach the map. Machines in
  // id order (std::map), so the flush is deterministic.
  for (auto& [id, st] : machines_) {
    if (st.history.size() < 2) continue;
    const BladePose &first = st.history.front(), &last = st.history.back();
    if (first.T_map_blade.isApprox(last.T_map_blade, 0.0)) continue;  // not moved at all: nothing to cut
    ctx.addCounter("final_partial_sweeps", 1);
    sweepHistory(ctx, st, id, last.stamp);
  }
  machines_.clear();
}

}  // namespace terramap::plugins
