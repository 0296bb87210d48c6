#pragma once
/// \file
/// The vertical datum `lidar_fusion` estimates between a machine's poses and a site survey, and
/// publishes on the RecordBus (type VerticalDatumRecord::kType) after each of that machine's
/// clouds, for the plugins that place the machine's tools in the map (`blade_sweep`).
///
/// Why: a surveyed site (a drone DEM, PointClouds of frame `survey`) is in the survey's datum;
/// the machine's poses come from GNSS/INS with a vertical bias and drift of centimetres, and so
/// do its LiDAR points and its blade. The mast LiDAR sees most of the site but not the ground
/// just ahead of the blade (the blade and its pile hide it), so the blade cuts ground the map
/// knows from the survey: the depth of cut is then survey ground minus a pose-frame edge, off by
/// the pose's bias. `lidar_fusion` measures that bias where its points fall on ground the
/// survey described and nothing has changed since (the median of point height minus survey
/// height), low-passes it, and brings the machine's clouds into the survey's datum; a tool
/// placed with the same offset cuts the map it sees.
///
/// Units and sign: `offset_m` is the machine's pose-frame height minus the survey's at the same
/// place, metres (a pose reading 1.5 cm high gives +0.015): subtract it from the z of the
/// machine's map-frame poses. Keyed by machine id: the part of a cloud's frame before the first
/// '/' (the simulator names clouds "<machine>/<sensor>"; BladePose::machine_id is the same id).
/// A machine without an entry has no estimate yet (no survey, or too few points on it).
///
/// Threading: immutable once published (shared as shared_ptr<const VerticalDatumRecord>).
#include <map>
#include <string>

namespace terramap {

struct VerticalDatumRecord {
  static constexpr const char* kType = "terramap.vertical_datum.v1";
  struct Machine {
    double offset_m = 0.0;  ///< pose frame minus survey datum (m); subtract from pose z
    double stamp = 0.0;     ///< stamp of the cloud of the latest update
    long points = 0;        ///< points on undisturbed surveyed ground in that update
    long updates = 0;       ///< clouds that updated it so far
  };
  std::map<std::string, Machine> machines;  ///< by machine id
};

}  // namespace terramap
