#pragma once
/// @file
/// pbve::bullet — Bullet Physics 3 behind pbve::Simulator: soft bodies (cloth, elastic and
/// stiff solids from the surface mesh) and rigid bodies (one per connected piece of the mesh).
///
/// Soft bodies are Bullet's position-based soft bodies (btSoftBody): one node per input-mesh
/// vertex (node i is vertex i), a link per triangle edge, optional bending links across each
/// interior edge, and for solids a volume-preserving force, an optional internal pressure and
/// shape matching. Rigid bodies are convex hulls of the mesh's connected pieces with mass
/// properties integrated over the closed piece. Collision planes are large static boxes.
///
/// Bullet is built in double precision here (Debian's `bullet-float64`), so state is saved and
/// restored without rounding. No Bullet header is included by this file.
///
/// Units are SI throughout: metres, kilograms, seconds, newtons, camera frame.

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pbve/core/mesh.hpp"
#include "pbve/sim/simulator.hpp"

namespace pbve::bullet {

/// Material model families.
enum class Material {
  cloth,    ///< soft surface: edge links and bending links, no volume
  elastic,  ///< soft closed surface that keeps its volume (jelly-like)
  stiff,    ///< soft closed surface with strong shape matching (nearly rigid, still deforms)
  rigid,    ///< rigid bodies: one per connected piece of the mesh
};

/// Parses "cloth", "elastic", "stiff" or "rigid"; throws std::invalid_argument otherwise.
Material material_from_string(const std::string& name);
/// The lowercase name of a material.
std::string to_string(Material m);

/// A collision plane; the object is kept on the side `normal` points to.
struct Plane {
  Eigen::Vector3d point = Eigen::Vector3d::Zero();     ///< a point on the plane, metres
  Eigen::Vector3d normal = Eigen::Vector3d(0, -1, 0);  ///< towards the free side
  double friction = 0.5;                               ///< Coulomb coefficient, >= 0
};

/// Physical and numerical parameters. Params::preset() fills every field for a material; each
/// field may then be overridden. Bullet's soft-body constraints are position based: the
/// dimensionless stiffnesses below are the fraction of a constraint's violation corrected per
/// solver iteration, so the apparent stiffness also grows with the number of substeps.
struct Params {
  Material material = Material::cloth;
  /// Cloth: areal density, kg/m^2 (node mass = density * area / 3 per adjacent triangle).
  /// Solids and rigid bodies: volumetric density, kg/m^3 (mass = density * enclosed volume;
  /// soft nodes share it in proportion to their surface area).
  double density = 0.3;
  /// Soft: stiffness of the edge links, in (0, 1] (Bullet's Material::m_kLST).
  double linear_stiffness = 0.9;
  /// Soft: stiffness of the bending links between the opposite vertices of each pair of
  /// adjacent triangles, in [0, 1]; 0 creates no bending links.
  double bending_stiffness = 0.1;
  /// Cloth, 1 or 0: simulate a thin closed surface (a board or a thick sheet made into cloth:
  /// two layers joined at a rim) as one sheet. The triangles of one layer (the smooth region
  /// grown from a vertex of a facing pair, pbve::opposite_layer_pairs()) are the Bullet cloth;
  /// every other vertex (the other layer and the rim) is attached to the closest point of that
  /// sheet at rest and follows it at its rest offset, in a frame that turns with the sheet, so
  /// the layers cannot pass through each other and the rim stays across the sheet's edge. The
  /// sheet's nodes carry the attached vertices' mass. Meshes that do not split into one such
  /// layer and the rest are simulated as two layers with ties (layer_stiffness). 0 always
  /// simulates every vertex.
  int single_sheet = 1;
  /// Cloth with two simulated layers (single_sheet = 0, or a surface that is not one sheet):
  /// stiffness of the links tying the two layers of a thin closed surface, in [0, 1] (0 creates
  /// none). Bullet's cloth has no self-collision, so without ties the back layer drifts
  /// through the front one. Each vertex is linked to the nearest vertex of the opposite layer
  /// (pbve::opposite_layer_pairs()). The links keep the layers' distance, not their alignment
  /// or order: the layers still slide and pass through each other where the cloth folds.
  double layer_stiffness = 0.5;
  /// Cloth: largest distance between the two layers of a thin closed surface (for the sheet and
  /// for the ties), metres; 0 uses pbve::default_layer_reach() (the mean edge length, or for a
  /// thin closed board whose faces lie farther apart, that length doubled until facing vertices lie
  /// within it, at most 5% of the bounding box's diagonal).
  double layer_distance = 0.0;
  /// Soft solids: shape matching, in [0, 1] (Bullet's kMT): each substep pulls every node this
  /// fraction of the way towards the best rigid motion of the rest shape. Must be 0 for cloth.
  double shape_matching = 0.0;
  /// Soft solids: bulk-modulus-like volume stiffness, Pa: a relative volume change dV / V0
  /// gives an inward or outward pressure of volume_stiffness * dV / V0 (Bullet's kVC =
  /// volume_stiffness / V0). 0 disables it; cloth ignores it.
  double volume_stiffness = 0.0;
  /// Soft solids: internal gas pressure at the rest volume, Pa (Bullet's kPR = pressure * V0,
  /// the pressure scales as V0 / V). 0 disables it; cloth ignores it.
  double pressure = 0.0;
  /// Soft: velocity damping per substep, in [0, 1) (Bullet's kDP).
  double damping = 0.01;
  /// Friction coefficient of the object, >= 0; a contact's friction is this times the plane's.
  /// Soft contacts cap the product at 1 (Bullet's soft contact sticks there); rigid contacts use
  /// Bullet's product of the two bodies' frictions.
  double friction = 1.0;
  /// Soft: position solver iterations per substep (>= 1).
  int position_iterations = 4;
  /// Collision margin, metres (> 0). Soft nodes keep this distance from planes; rigid hulls
  /// rest on them (their contacts become active within this distance).
  double collision_margin = 0.002;
  /// Rigid: fraction of the linear velocity lost per second, in [0, 1].
  double linear_damping = 0.0;
  /// Rigid: fraction of the angular velocity lost per second, in [0, 1].
  double angular_damping = 0.0;
  /// Rigid: coefficient of restitution of contacts, in [0, 1].
  double restitution = 0.0;
  /// Rigid: a piece whose convex hull exceeds its volume by more than this fraction (>= 0) is
  /// concave and collides as its triangle mesh (btGImpactMeshShape); the others collide as
  /// their hulls, which is cheaper and steadier. A large value makes every piece a hull.
  double hull_tolerance = 0.05;
  /// Gravitational acceleration, m/s^2, camera frame (+y is down in the image).
  Eigen::Vector3d gravity{0.0, 9.81, 0.0};
  /// Bullet steps per step() (>= 1); each is one stepSimulation() of dt / substeps.
  int substeps = 10;
  /// Collision planes (default none).
  std::vector<Plane> planes;

  /// Defaults for a material:
  /// - cloth: 0.3 kg/m^2, links 0.9, bending 0.1, a thin closed surface as one sheet (else
  ///   layer ties 0.5), damping 0.01, 4 iterations, margin 2 mm;
  /// - elastic: 1000 kg/m^3, links 0.2, bending 0.1, volume 2e4 Pa, shape matching 0.01,
  ///   damping 0.02, 4 iterations;
  /// - stiff: 1000 kg/m^3, links 1, bending 1, volume 2e6 Pa, shape matching 0.5, damping
  ///   0.02, 8 iterations;
  /// - rigid: 1000 kg/m^3, friction 1, no damping, restitution 0, margin 1 mm.
  static Params preset(Material m);

  /// Throws std::invalid_argument naming the first invalid field.
  void validate() const;
};

/// Bullet soft or rigid bodies behind pbve::Simulator.
///
/// Soft materials: one node per vertex, control = one force per vertex (ControlSpace::
/// vertex_force). Anchored nodes have zero inverse mass and are moved kinematically along the
/// linear interpolation of their targets over the substeps; after step() they are exactly at
/// their targets. Their control blocks exist (with the node's nominal mass) but are ignored.
/// A thin closed cloth simulated as one sheet (Params::single_sheet) has nodes for one layer
/// only; a force on an attached vertex acts on the sheet point that carries it, an anchored
/// attached vertex is reported exactly at its target and holds the nodes that carry it (they
/// follow the least-squares rigid motion of all anchors), and block masses stay each vertex's
/// own share of the object's mass (a node also carries its attached vertices' shares).
///
/// Rigid material: one body per connected piece (vertices joined by triangles), control = one
/// force + torque per body at its centre of mass (ControlSpace::body_wrench). A body with an
/// anchored vertex is kinematic: each substep it takes the rigid transform that best fits its
/// anchors' interpolated targets (least squares); its anchored vertices are reported exactly at
/// their targets, its other vertices follow the fitted transform, and its control block is
/// ignored. Convex pieces collide as their hulls, concave ones as their triangle meshes.
///
/// Exact replay: every step() starts from a normalized world (all objects removed and re-added
/// in a fixed order, broadphase reset, so no pair or contact manifold survives from an earlier
/// step) and a rebuilt node tree, so the result of a step is a function of the saved state and
/// the step's inputs alone. save() copies the node states (x, q, v, f, normals; for a single
/// sheet also the anchors' positions) or body transforms and velocities; clone() rebuilds the
/// world from the same recipe (sharing a single sheet's attachments) and restores.
class BulletSimulator final : public Simulator {
 public:
  /// @param mesh       topology (triangles); its vertices are not used
  /// @param positions  #V by 3 rest positions, camera frame, metres; the simulation starts here
  ///                   at zero velocity
  /// @param anchors    anchored vertex ids (any order, no duplicates)
  /// @param params     physics and numerics (validated)
  /// Throws std::invalid_argument on wrong sizes, out-of-range or duplicate anchors, invalid
  /// parameters, a solid or rigid material on a piece that encloses no volume.
  BulletSimulator(const Mesh& mesh, const Vertices& positions, std::vector<int> anchors,
                  const Params& params);
  /// Same, with the mesh's own vertices as rest positions.
  BulletSimulator(const Mesh& mesh, std::vector<int> anchors, const Params& params);
  ~BulletSimulator() override;
  BulletSimulator(const BulletSimulator&) = delete;
  BulletSimulator& operator=(const BulletSimulator&) = delete;

  std::string name() const override { return "bullet"; }
  int num_vertices() const override;
  Vertices positions() const override;
  Vertices velocities() const override;
  ControlLayout control_layout() const override;
  std::vector<int> anchors() const override;
  void step(const StepInput& in) override;
  /// Estimated from the change of momentum: m (v_end - v_start) / dt - u per free vertex
  /// (soft), or the body's m (v_end - v_start) / dt - f_control shared equally by its vertices
  /// (rigid). Bullet does not expose its constraint and contact forces.
  Vertices physical_forces() const override;
  /// |m g| + |physical force - m g| per vertex (gravity and the rest counted separately).
  Eigen::VectorXd physical_force_magnitudes() const override;
  SimState save() const override;
  void restore(const SimState& state) override;
  std::unique_ptr<Simulator> clone() const override;

  /// Parameters in use.
  const Params& params() const;
  /// Rigid: number of bodies; soft: 1.
  int num_bodies() const;
  /// Soft: node masses (kg, 0 for anchors); rigid: body masses.
  Eigen::VectorXd masses() const;
  /// Rigid: centre of mass of each body, camera frame, #bodies by 3. Soft: the mass-weighted
  /// mean of the free nodes (one row).
  Vertices centers_of_mass() const;
  /// Cloth: number of links tying the two layers of a thin closed surface (layer_stiffness);
  /// 0 for other materials, a single sheet, or when none were found.
  int num_layer_ties() const;
  /// Soft: Bullet nodes (the vertices, or one layer's vertices for a single sheet); rigid: 0.
  int num_nodes() const;
  /// Soft: the vertex of each Bullet node, ascending (every vertex without a single sheet);
  /// rigid: empty.
  std::vector<int> node_vertices() const;

 private:
  BulletSimulator();  // for clone()
  struct Impl;
  std::unique_ptr<Impl> m_impl;
};

}  // namespace pbve::bullet
