#pragma once
/// \file
/// Contact between machines (docs/sim.md "Machines collide"): the solid boxes of each machine's
/// shape (machine_shape.hpp, the boxes its LiDAR sees) are kept from interpenetrating. Each
/// physics step, after every machine has moved, overlapping pairs are pushed apart along the
/// minimum-translation direction of the deepest overlapping box pair, and the speeds with which
/// they approach each other along that direction are removed by a perfectly inelastic impulse
/// (momentum along the contact normal conserved; a heavy machine shoves a light one further).
///
/// A tracked machine moves along its heading only (its tracks resist sliding sideways, so the
/// ground, not the other machine, takes the lateral share): each machine's mobility along the
/// contact normal n is (heading . n)^2 / mass, the effective inverse mass of a body constrained
/// to its heading. Only when neither machine can move along n that way (both contacts nearly
/// side-on, |heading . n| < 0.5 for both) are they slid apart sideways by the mass ratio.
/// Pushing then follows from each machine's own drive and traction: a machine driving into a
/// standing one shares its speed with it at the contact, the standing one's tracks brake it
/// (Janosi–Hanamoto, its lever at zero) and the pusher's drive pushes on; two machines driving
/// head-on stop apart with their tracks slipping.
///
/// Geometry: each placed box is taken as the vertical prism over its horizontal projection (the
/// convex hull of its 8 corners in x, y) between its lowest and highest corner; two boxes touch
/// when their prisms overlap (separating-axis test on the two hulls, and the z intervals). The
/// prism holds the tilted box, so a contact is never missed; it may be found up to the box's
/// tilt early. Units: metres, kilograms, m/s. Deterministic (pairs in index order); not
/// thread-safe.
#include <terramap/sim/ctl.hpp>
#include <terramap/sim/machine_shape.hpp>

#include <Eigen/Core>

#include <vector>

namespace terramap::sim {

/// One machine in the contact pass: its loader model (moved in place) and its boxes at its
/// current true pose (placeShape; an excavator's link boxes included).
struct ContactBody {
  CompactTrackLoader* machine = nullptr;
  std::vector<PlacedBox> boxes;
};

/// The deepest overlap of two sets of boxes: `depth` (m, > 0 when they overlap) along the unit
/// horizontal `normal` pointing from a to b. depth <= 0: no overlap (normal undefined).
struct BoxOverlap {
  double depth = 0;
  Eigen::Vector2d normal = Eigen::Vector2d::UnitX();
};
BoxOverlap deepestOverlap(const std::vector<PlacedBox>& a, const std::vector<PlacedBox>& b);

/// What a contact pass did.
struct ContactStats {
  int contacts = 0;        ///< overlapping pairs found (counting repeats over the iterations)
  double max_depth_m = 0;  ///< deepest overlap resolved
};

/// Separates every overlapping pair of `bodies` and removes their approach speeds (see the file
/// comment); at most `iterations` sweeps over the pairs (a machine squeezed between two others
/// needs more than one). Moves the machines through CompactTrackLoader::contactMove, which keeps
/// them on `terrain`. Updates each body's boxes by the horizontal moves.
ContactStats resolveMachineContacts(std::vector<ContactBody>& bodies, const TruthTerrain& terrain, int iterations = 4);

}  // namespace terramap::sim
