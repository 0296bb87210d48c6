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
/// Share of the maximum tractive effort a track of contact length L mobilises at slip i
/// (Janosi–Hanamoto): 1 - K / (i L) (1 - exp(-i L / K)) for i > 0, odd in i, 0 at i = 0.
double janosiShare(double slip, double contact_length_m, double shear_k_m);

}  // namespace terramap::sim
