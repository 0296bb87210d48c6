#pragma once
/// \file
/// Track–soil interaction of tracked machines (docs/sim.md "Track–soil interaction"): Bekker's
/// pressure–sinkage relation p = (k_c / b + k_phi) z^n for the static sinkage and the compaction
/// (motion) resistance of a track, the Mohr–Coulomb limit A c + W tan(phi) of the tractive
/// effort with the Janosi–Hanamoto shear–displacement law for how much of it a slip mobilises.
/// References: M. G. Bekker, *Introduction to Terrain-Vehicle Systems* (1969); J. Y. Wong,
/// *Theory of Ground Vehicles* (Wiley), chapters 2-3 and its table of measured terrain values.
/// Units SI: k_c in N/m^(n+1), k_phi in N/m^(n+2), lengths m, pressures Pa, forces N.
/// Pure functions: safe from any thread.
#include <terramap/soil/soil_table.hpp>

#include <array>

namespace terramap::sim {

/// The terrain values of one soil (Bekker's n, k_c, k_phi; Janosi–Hanamoto's K).
struct Terramechanics {
  double n = 1;        ///< sinkage exponent
  double k_c = 0;      ///< cohesive modulus, N/m^(n+1)
  double k_phi = 0;    ///< frictional modulus, N/m^(n+2)
  double shear_k_m = 0.025;  ///< shear deformation modulus K, m
};

/// The table row for (family, I_d): n linear and k_c, k_phi, K log-linear in I_d between a
/// loose and a dense end member (docs/sim.md lists them and their sources).
/// \throws std::invalid_argument for I_d outside [0, 1].
Terramechanics terramechanics(soil::SoilFamily family, double relative_density);

/// Static sinkage z (m) of a track of width b (m) under the mean ground pressure p (Pa).
double bekkerSinkage(const Terramechanics& t, double pressure_pa, double width_m);
/// Compaction resistance of one track (N) that sank z: the work of pressing a rut of width b,
/// per metre travelled: b (k_c / b + k_phi) z^(n+1) / (n + 1).
double compactionResistance(const Terramechanics& t, double sinkage_m, double width_m);
/// Bulldozing resistance of one track of width b (N) whose leading edge meets soil (c Pa, phi
/// rad, unit weight gamma N/m^3) it has sunk z into: the passive earth pressure of the soil wedge
/// pushed ahead of it, b (0.667 c z K_pc + 0.5 gamma z^2 K_pgamma) with K_pc = (N_c - tan phi)
/// cos^2 phi and K_pgamma = (2 N_gamma / tan phi + 1) cos^2 phi (Bekker's, in the simplified form
/// of J. Y. Wong, *Theory of Ground Vehicles*, ch. 2, for a rigid wheel; the leading edge of a
/// track meets the soil the same way). N_c, N_q of Prandtl and Reissner (fee::
/// bearingFactors), N_gamma = 2 (N_q + 1) tan phi (Vesic 1973). 0 for z <= 0 or phi <= 0.
double bulldozingResistance(double c_pa, double phi_rad, double gamma_n_m3, double sinkage_m, double width_m);
/// Share of the maximum tractive effort a track of contact length L mobilises at slip i
/// (Janosi–Hanamoto): 1 - K / (i L) (1 - exp(-i L / K)) for i > 0, odd in i, 0 at i = 0.
double janosiShare(double slip, double contact_length_m, double shear_k_m);

class CompactTrackLoader;
class SoilField;
class TruthTerrain;
struct CtlLoad;
struct MachineSpec;

/// A tracked machine's steady straight travel on flat ground of one soil at a set track speed
/// (the state CompactTrackLoader::step settles into with MachineSpec::track_soil; docs/sim.md
/// "TERA's Fig. 4"): the tracks carry the running gear's rolling_resistance W plus both ruts'
/// compaction and bulldozing resistances by slipping until their Janosi–Hanamoto share of the
/// traction limit min(A c + W tan phi, max_drive_force_n) equals that resistance.
struct SteadyTravel {
  double pressure_pa = 0;       ///< mean ground pressure W / (2 b L), Pa
  double sinkage_m = 0;         ///< rut depth: Bekker's sinkage under rut_pressure_factor x that, m
  double compaction_n = 0;      ///< both tracks' compaction resistance, N
  double bulldozing_n = 0;      ///< both tracks' bulldozing resistance, N
  double resistance_n = 0;      ///< rolling_resistance W + compaction + bulldozing, N
  double traction_limit_n = 0;  ///< min(A c + W tan phi, max drive force), N
  /// The slip i at which traction_limit_n x janosiShare(i) = resistance_n (the speed is the
  /// track speed x (1 - i)); NaN when even full slip cannot carry the resistance (the machine
  /// stops).
  double slip = 0;
};

/// SteadyTravel of machine `m` (its mass, track width, length, rolling resistance and drive
/// limit) on soil (family, I_d). `rut_pressure_factor` scales the pressure that sets the rut's
/// depth above the mean ground pressure (1: uniform pressure, what the simulator assumes; a
/// larger one asks what pressure peaks under the rollers would do to the same machine, whose
/// weight and so traction limit stay), the rut's compaction being the work of pressing it to
/// that depth, however loaded. Pure.
/// \throws std::invalid_argument for I_d outside [0, 1] or a factor <= 0.
SteadyTravel steadyTravel(const MachineSpec& m, soil::SoilFamily family, double relative_density,
                          double rut_pressure_factor = 1.0);

/// The ground under machine `m` for its next step (MachineSpec::track_soil): the Mohr–Coulomb
/// terms and K of the soil under its centre, the compaction and bulldozing resistances of both
/// tracks in the soil under their leading halves (where the rut is pressed: the front halves
/// driving forward, the rear ones reversing), and the static sinkage and n of the soil under each track half's
/// centre (CtlLoad::support_sinkage_m).
/// Soil at a point is the soil at the current surface's depth below the initial one.
void trackGround(const TruthTerrain& terrain, const SoilField& soil, const CompactTrackLoader& m, CtlLoad& load);

}  // namespace terramap::sim
