#include "pbve/bullet/bullet.hpp"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>

#include <BulletCollision/CollisionShapes/btConvexHullShape.h>
#include <BulletCollision/CollisionShapes/btConvexPolyhedron.h>
#include <BulletCollision/CollisionShapes/btTriangleIndexVertexArray.h>
#include <BulletCollision/Gimpact/btGImpactCollisionAlgorithm.h>
#include <BulletCollision/Gimpact/btGImpactShape.h>
#include <BulletSoftBody/btSoftBody.h>
#include <BulletSoftBody/btSoftBodyRigidBodyCollisionConfiguration.h>
#include <BulletSoftBody/btSoftRigidDynamicsWorld.h>
#include <btBulletDynamicsCommon.h>
#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>

#include "pbve/core/thin_sheet.hpp"

static_assert(sizeof(btScalar) == sizeof(double),
              "pbve::bullet expects Bullet built in double precision (bullet-float64)");

namespace pbve::bullet {

namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

btVector3 to_bt(const Vector3d& v) {
  return btVector3(v.x(), v.y(), v.z());
}
Vector3d to_eigen(const btVector3& v) {
  return Vector3d(v.x(), v.y(), v.z());
}
btMatrix3x3 to_bt_matrix(const Matrix3d& m) {
  return btMatrix3x3(m(0, 0), m(0, 1), m(0, 2), m(1, 0), m(1, 1), m(1, 2), m(2, 0), m(2, 1),
                     m(2, 2));
}
Matrix3d to_eigen(const btMatrix3x3& m) {
  Matrix3d out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out(r, c) = m[r][c];
  return out;
}

[[noreturn]] void fail(const std::string& what) {
  throw std::invalid_argument("bullet: " + what);
}

/// What the world is built from; shared by clones.
struct Recipe {
  Triangles triangles;
  Vertices rest;             // #V by 3, camera frame
  std::vector<int> anchors;  // sorted
  Params params;
};

/// Volume, centre and second moment of a closed triangulated surface.
struct VolumeIntegrals {
  double volume = 0.0;
  Vector3d center = Vector3d::Zero();
  Matrix3d second = Matrix3d::Zero();  // integral of (x - c)(x - c)^T over the volume, m^5
};

VolumeIntegrals volume_integrals(const Vertices& x, const std::vector<Eigen::Vector3i>& tris) {
  Vector3d origin = Vector3d::Zero();
  for (const auto& t : tris)
    for (int k = 0; k < 3; ++k) origin += x.row(t(k)).transpose();
  origin /= std::max<double>(1.0, 3.0 * static_cast<double>(tris.size()));
  // Signed tetrahedra (origin, a, b, c): volume det/6, first moment det/24 (a+b+c), second
  // moment det * A C A^T with the canonical tetrahedron's C = [2 1 1; 1 2 1; 1 1 2] / 120.
  Matrix3d canon;
  canon << 2, 1, 1, 1, 2, 1, 1, 1, 2;
  canon /= 120.0;
  double volume = 0.0;
  Vector3d first = Vector3d::Zero();
  Matrix3d second = Matrix3d::Zero();
  for (const auto& t : tris) {
    Matrix3d a;
    for (int k = 0; k < 3; ++k) a.col(k) = x.row(t(k)).transpose() - origin;
    const double det = a.determinant();
    volume += det / 6.0;
    first += det / 24.0 * (a.col(0) + a.col(1) + a.col(2));
    second += det * a * canon * a.transpose();
  }
  VolumeIntegrals out;
  out.volume = volume;
  if (volume > 0.0) {
    const Vector3d c = first / volume;
    out.center = origin + c;
    out.second = second - volume * c * c.transpose();
  }
  return out;
}

/// A rigid piece: a connected component of the mesh.
struct Piece {
  std::vector<int> vertices;                       // global vertex ids
  Eigen::Matrix<double, Eigen::Dynamic, 3> local;  // body-frame coordinates, rows as vertices
  double mass = 0.0;
  Vector3d inertia = Vector3d::Zero();  // principal moments, kg m^2
  Matrix3d rotation0 = Matrix3d::Identity();
  Vector3d center0 = Vector3d::Zero();
  std::vector<int> anchor_rows;   // rows of the anchor list that belong to this piece
  std::vector<int> anchor_local;  // their row in `local`
  double radius2 = 0.0;           // squared extent about the centre, m^2
  bool concave = false;           // collides as its triangle mesh rather than its hull
  std::vector<double> mesh_xyz;   // concave: body-frame vertices, x y z per vertex
  std::vector<int> mesh_tris;     // concave: triangles, indices into mesh_xyz's vertices
};

/// Volume of a convex polyhedron (Bullet's polyhedral features of a hull), m^3.
double hull_volume(const btConvexPolyhedron& poly) {
  btVector3 c(0, 0, 0);
  for (int i = 0; i < poly.m_vertices.size(); ++i) c += poly.m_vertices[i];
  if (poly.m_vertices.size() > 0) c /= static_cast<double>(poly.m_vertices.size());
  double volume = 0.0;
  for (int f = 0; f < poly.m_faces.size(); ++f) {
    const auto& idx = poly.m_faces[f].m_indices;
    for (int k = 1; k + 1 < idx.size(); ++k) {
      const btVector3 a = poly.m_vertices[idx[0]] - c, b = poly.m_vertices[idx[k]] - c,
                      d = poly.m_vertices[idx[k + 1]] - c;
      volume += std::abs(a.dot(b.cross(d))) / 6.0;
    }
  }
  return volume;
}

/// Rotation R (and t) of the least-squares rigid fit R p + t ~ q; `prior` regularizes the
/// directions the points do not determine (fewer than three non-collinear points).
void fit_rigid(const Eigen::Matrix<double, Eigen::Dynamic, 3>& p,
               const Eigen::Matrix<double, Eigen::Dynamic, 3>& q, const Matrix3d& prior,
               double scale2, Matrix3d* r, Vector3d* t) {
  const Vector3d pc = p.colwise().mean().transpose();
  const Vector3d qc = q.colwise().mean().transpose();
  Matrix3d m = 1e-9 * std::max(scale2, 1e-12) * prior;
  for (Eigen::Index i = 0; i < p.rows(); ++i)
    m += (q.row(i).transpose() - qc) * (p.row(i).transpose() - pc).transpose();
  Eigen::JacobiSVD<Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Matrix3d d = Matrix3d::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) d(2, 2) = -1.0;
  *r = svd.matrixU() * d * svd.matrixV().transpose();
  *t = qc - *r * pc;
}

constexpr double kPlaneHalfSize = 100.0;      // m, lateral half extent of a plane's box
constexpr double kPlaneHalfThickness = 10.0;  // m

}  // namespace

struct BulletSimulator::Impl {
  std::shared_ptr<const Recipe> recipe;
  int num_vertices = 0;
  bool rigid = false;
  std::vector<char> anchored;  // per vertex

  // Bullet objects (destroyed in ~Impl in the right order).
  std::unique_ptr<btSoftBodyRigidBodyCollisionConfiguration> config;
  std::unique_ptr<btCollisionDispatcher> dispatcher;
  std::unique_ptr<btDbvtBroadphase> broadphase;
  std::unique_ptr<btSequentialImpulseConstraintSolver> solver;
  std::unique_ptr<btSoftRigidDynamicsWorld> world;
  std::vector<std::unique_ptr<btCollisionShape>> shapes;  // the planes' boxes
  // Rigid: the pieces' hulls. Shapes are not modified by a simulation, so clones share them.
  std::vector<std::shared_ptr<btConvexHullShape>> hulls;
  // Rigid, concave pieces: their triangle meshes (GImpact shapes keep per-query state, so each
  // world has its own).
  std::vector<std::unique_ptr<btTriangleIndexVertexArray>> mesh_arrays;
  std::vector<std::unique_ptr<btGImpactMeshShape>> mesh_shapes;
  std::vector<std::unique_ptr<btRigidBody>> planes;
  std::unique_ptr<btSoftBody> soft;
  std::vector<std::unique_ptr<btRigidBody>> bodies;

  // Soft.
  Eigen::VectorXd vertex_mass;  // nominal mass per vertex (also for anchors), kg
  int layer_ties = 0;           // links between the layers of a thin closed cloth
  // A thin closed cloth simulated as one sheet (Params::single_sheet); null otherwise. Shared
  // by clones (it only depends on the recipe).
  std::shared_ptr<const ThinSheet> sheet;
  std::vector<int> node_vertex;  // per Bullet node: its vertex (the identity without a sheet)
  std::vector<int> vertex_node;  // per vertex: its Bullet node, -1 when attached to the sheet
  Eigen::VectorXd carried_mass;  // per Bullet node: its own mass and its attached vertices' share
  // Anchored Bullet nodes: `row` is the node's own row of the anchor list, or -1 for a sheet
  // node that carries an anchored attached vertex and follows the anchors' rigid fit.
  struct NodeAnchor {
    int node = 0;
    int row = -1;
  };
  std::vector<NodeAnchor> node_anchors;
  // Rigid.
  std::vector<Piece> pieces;
  std::vector<int> vertex_piece;  // per vertex, -1 when in no triangle
  // Rigid, and soft with a sheet: current anchor positions (#anchors by 3).
  Vertices anchor_pos;

  // Last step's averaged physical forces and their magnitudes.
  Vertices phys;
  Eigen::VectorXd phys_norm;

  /// Builds the world of `r`; `like` (an Impl of the same recipe) lends its rigid pieces.
  explicit Impl(std::shared_ptr<const Recipe> r, const Impl* like = nullptr);
  ~Impl();

  void build_world();
  void add_planes();
  void build_soft(const Impl* like);
  Vertices node_positions() const;
  void build_pieces();
  void build_rigid(const Impl* like);
  void normalize();
  void step(const StepInput& in);
  Vertices positions() const;
  Vertices velocities() const;
  ControlLayout layout() const;
  SimState save() const;
  void restore(const SimState& s);
  size_t state_size() const;
};

BulletSimulator::Impl::Impl(std::shared_ptr<const Recipe> r, const Impl* like)
    : recipe(std::move(r)) {
  const Recipe& rc = *recipe;
  num_vertices = static_cast<int>(rc.rest.rows());
  rigid = rc.params.material == Material::rigid;
  anchored.assign(static_cast<size_t>(num_vertices), 0);
  for (int a : rc.anchors) anchored[static_cast<size_t>(a)] = 1;
  phys = Vertices::Zero(num_vertices, 3);
  phys_norm = Eigen::VectorXd::Zero(num_vertices);
  build_world();
  add_planes();
  if (rigid)
    build_rigid(like);
  else
    build_soft(like);
}

BulletSimulator::Impl::~Impl() {
  if (world) {
    if (soft) world->removeSoftBody(soft.get());
    for (auto& b : bodies) world->removeRigidBody(b.get());
    for (auto& p : planes) world->removeRigidBody(p.get());
  }
  soft.reset();
  world.reset();
  solver.reset();
  broadphase.reset();
  dispatcher.reset();
  config.reset();
  bodies.clear();
  planes.clear();
  shapes.clear();
  hulls.clear();
  mesh_shapes.clear();
  mesh_arrays.clear();
}

void BulletSimulator::Impl::build_world() {
  // Small pools (Bullet allocates beyond them on demand): the default 4096 manifolds and
  // algorithms make every world, hence every clone(), allocate and touch megabytes.
  btDefaultCollisionConstructionInfo cci;
  cci.m_defaultMaxPersistentManifoldPoolSize = 64;
  cci.m_defaultMaxCollisionAlgorithmPoolSize = 64;
  config = std::make_unique<btSoftBodyRigidBodyCollisionConfiguration>(cci);
  dispatcher = std::make_unique<btCollisionDispatcher>(config.get());
  broadphase = std::make_unique<btDbvtBroadphase>();
  solver = std::make_unique<btSequentialImpulseConstraintSolver>();
  world = std::make_unique<btSoftRigidDynamicsWorld>(dispatcher.get(), broadphase.get(),
                                                     solver.get(), config.get());
  btGImpactCollisionAlgorithm::registerAlgorithm(dispatcher.get());
  const Params& p = recipe->params;
  world->setGravity(to_bt(p.gravity));
  btSoftBodyWorldInfo& info = world->getWorldInfo();
  info.m_gravity = to_bt(p.gravity);
  info.air_density = 0;
  info.water_density = 0;
  info.m_sparsesdf.Initialize();
}

void BulletSimulator::Impl::add_planes() {
  const Params& p = recipe->params;
  for (const Plane& pl : p.planes) {
    const Vector3d n = pl.normal.normalized();
    auto box = std::make_unique<btBoxShape>(
        btVector3(kPlaneHalfSize, kPlaneHalfSize, kPlaneHalfThickness));
    box->setMargin(std::min(p.collision_margin, 0.5 * kPlaneHalfThickness));
    box->initializePolyhedralFeatures();
    // The box's +z face lies on the plane.
    btTransform tr;
    tr.setIdentity();
    tr.setRotation(shortestArcQuat(btVector3(0, 0, 1), to_bt(n)));
    tr.setOrigin(to_bt(pl.point - kPlaneHalfThickness * n));
    btRigidBody::btRigidBodyConstructionInfo ci(0.0, nullptr, box.get());
    ci.m_startWorldTransform = tr;
    // Rigid contacts multiply the two frictions (and restitutions); soft contacts use the
    // plane's friction times kDF = 1, where a product above 1 would not be meaningful.
    ci.m_friction = rigid ? pl.friction : std::min(1.0, pl.friction * p.friction);
    ci.m_restitution = 1.0;
    auto body = std::make_unique<btRigidBody>(ci);
    world->addRigidBody(body.get());
    shapes.push_back(std::move(box));
    planes.push_back(std::move(body));
  }
}

void BulletSimulator::Impl::build_soft(const Impl* like) {
  const Recipe& rc = *recipe;
  const Params& p = rc.params;
  const Vertices& x = rc.rest;
  const int n = num_vertices;
  const Triangles& t = rc.triangles;

  // Masses: cloth by area (density per m^2); solids by volume, shared by surface area.
  Eigen::VectorXd area = Eigen::VectorXd::Zero(n);
  double total_area = 0.0;
  for (Eigen::Index f = 0; f < t.rows(); ++f) {
    const Vector3d a = x.row(t(f, 0)).transpose(), b = x.row(t(f, 1)).transpose(),
                   c = x.row(t(f, 2)).transpose();
    const double af = 0.5 * (b - a).cross(c - a).norm();
    total_area += af;
    for (int k = 0; k < 3; ++k) area(t(f, k)) += af / 3.0;
  }
  double rest_volume = 0.0;
  if (p.material == Material::cloth) {
    vertex_mass = p.density * area;
  } else {
    if (const auto hole = first_boundary_edge(t))
      fail("material " + to_string(p.material) +
           " needs a closed mesh; the edge between vertices " + std::to_string(hole->first) +
           " and " + std::to_string(hole->second) + " borders a hole (an open surface is cloth)");
    std::vector<Eigen::Vector3i> tris;
    for (Eigen::Index f = 0; f < t.rows(); ++f) tris.emplace_back(t(f, 0), t(f, 1), t(f, 2));
    rest_volume = volume_integrals(x, tris).volume;
    if (!(rest_volume > 0.0))
      fail("material " + to_string(p.material) +
           " needs a closed mesh enclosing a positive volume (counter-clockwise triangles seen "
           "from outside); enclosed volume " +
           std::to_string(rest_volume) + " m^3");
    vertex_mass = (p.density * rest_volume / total_area) * area;
  }
  // A vertex in no triangle gets the mean mass (it is a free particle).
  const double mean_mass = vertex_mass.sum() / std::max(1, n);
  for (int i = 0; i < n; ++i)
    if (!(vertex_mass(i) > 0.0)) vertex_mass(i) = mean_mass > 0.0 ? mean_mass : 1e-3;

  const double reach = p.layer_distance > 0.0 ? p.layer_distance : default_layer_reach(x, t);
  auto key = [](int a, int b) { return std::make_pair(std::min(a, b), std::max(a, b)); };

  // A thin closed cloth as one sheet: its nodes are the vertices of one layer.
  if (like) {
    sheet = like->sheet;
  } else if (p.material == Material::cloth && p.single_sheet != 0 && reach > 0.0) {
    if (auto s = make_thin_sheet(x, t, reach))
      sheet = std::make_shared<const ThinSheet>(std::move(*s));
  }
  if (sheet) {
    node_vertex = sheet->node_vertex;
    vertex_node = sheet->vertex_node;
  } else {
    node_vertex.resize(static_cast<size_t>(n));
    std::iota(node_vertex.begin(), node_vertex.end(), 0);
    vertex_node = node_vertex;
  }
  const int nn = static_cast<int>(node_vertex.size());
  // The node triangles and rest positions.
  Triangles nt = sheet ? sheet->triangles : t;
  Vertices nx(nn, 3);
  for (int i = 0; i < nn; ++i) nx.row(i) = x.row(node_vertex[static_cast<size_t>(i)]);

  // Node masses: each node carries its vertex and its share of the attached vertices.
  carried_mass.resize(nn);
  for (int i = 0; i < nn; ++i) carried_mass(i) = vertex_mass(node_vertex[static_cast<size_t>(i)]);
  std::vector<char> node_anchored(static_cast<size_t>(nn), 0);
  node_anchors.clear();
  for (size_t row = 0; row < rc.anchors.size(); ++row) {
    const int node = vertex_node[static_cast<size_t>(rc.anchors[row])];
    if (node < 0) continue;
    node_anchored[static_cast<size_t>(node)] = 1;
    node_anchors.push_back({node, static_cast<int>(row)});
  }
  if (sheet) {
    for (int v = 0; v < n; ++v) {
      if (vertex_node[static_cast<size_t>(v)] >= 0) continue;
      const SheetAttachment& a = sheet->attachment[static_cast<size_t>(v)];
      for (int k = 0; k < 3; ++k) {
        const int node = nt(a.triangle, k);
        carried_mass(node) += a.bary[k] * vertex_mass(v);
        // An anchored attached vertex holds the nodes that carry it.
        if (anchored[static_cast<size_t>(v)] && a.bary[k] > 1e-6 &&
            !node_anchored[static_cast<size_t>(node)]) {
          node_anchored[static_cast<size_t>(node)] = 1;
          node_anchors.push_back({node, -1});
        }
      }
    }
    std::sort(node_anchors.begin(), node_anchors.end(),
              [](const NodeAnchor& a, const NodeAnchor& b) { return a.node < b.node; });
    anchor_pos.resize(static_cast<Eigen::Index>(rc.anchors.size()), 3);
    for (size_t i = 0; i < rc.anchors.size(); ++i)
      anchor_pos.row(static_cast<Eigen::Index>(i)) = x.row(rc.anchors[i]);
  }

  std::vector<btVector3> xs(static_cast<size_t>(nn));
  std::vector<btScalar> ms(static_cast<size_t>(nn));
  for (int i = 0; i < nn; ++i) {
    xs[static_cast<size_t>(i)] = to_bt(nx.row(i).transpose());
    ms[static_cast<size_t>(i)] = node_anchored[static_cast<size_t>(i)] ? 0.0 : carried_mass(i);
  }
  soft = std::make_unique<btSoftBody>(&world->getWorldInfo(), nn, xs.data(), ms.data());
  btSoftBody& sb = *soft;
  sb.m_materials[0]->m_kLST = p.linear_stiffness;
  sb.m_materials[0]->m_kAST = 1.0;
  sb.m_materials[0]->m_kVST = 1.0;

  // Edge links (each undirected edge once, in order of first appearance) and faces.
  std::set<std::pair<int, int>> links;
  std::map<std::pair<int, int>, std::vector<int>> edge_opposite;
  for (Eigen::Index f = 0; f < nt.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = nt(f, k), b = nt(f, (k + 1) % 3), c = nt(f, (k + 2) % 3);
      if (links.insert(key(a, b)).second) sb.appendLink(a, b);
      edge_opposite[key(a, b)].push_back(c);
    }
    sb.appendFace(nt(f, 0), nt(f, 1), nt(f, 2));
  }
  // Bending links across interior edges, in a deterministic (sorted edge) order.
  if (p.bending_stiffness > 0.0) {
    btSoftBody::Material* bend = sb.appendMaterial();
    bend->m_kLST = p.bending_stiffness;
    bend->m_kAST = 1.0;
    bend->m_kVST = 1.0;
    for (const auto& [edge, opp] : edge_opposite) {
      if (opp.size() != 2 || opp[0] == opp[1]) continue;
      if (links.insert(key(opp[0], opp[1])).second) {
        sb.appendLink(opp[0], opp[1], bend);
        sb.m_links[sb.m_links.size() - 1].m_bbending = 1;
      }
    }
  }

  // Ties between the layers of a thin closed cloth simulated as two layers, after the bending
  // links.
  if (!sheet && p.material == Material::cloth && p.layer_stiffness > 0.0 && reach > 0.0) {
    btSoftBody::Material* tie = sb.appendMaterial();
    tie->m_kLST = p.layer_stiffness;
    tie->m_kAST = 1.0;
    tie->m_kVST = 1.0;
    for (const auto& [a, b] : opposite_layer_pairs(x, t, reach)) {
      if (!links.insert(key(a, b)).second) continue;
      sb.appendLink(a, b, tie);
      ++layer_ties;
    }
  }

  sb.m_cfg.piterations = p.position_iterations;
  sb.m_cfg.viterations = 0;
  sb.m_cfg.diterations = 0;
  sb.m_cfg.citerations = 0;
  sb.m_cfg.kDP = p.damping;
  sb.m_cfg.kDF = 1.0;
  sb.m_cfg.kKHR = 1.0;
  sb.m_cfg.kCHR = 1.0;
  sb.m_cfg.kMT = p.material == Material::cloth ? 0.0 : p.shape_matching;
  sb.m_cfg.kVC = p.material == Material::cloth ? 0.0 : p.volume_stiffness / rest_volume;
  sb.m_cfg.kPR = p.material == Material::cloth ? 0.0 : p.pressure * rest_volume;
  sb.m_cfg.collisions = btSoftBody::fCollision::SDF_RS;
  sb.getCollisionShape()->setMargin(p.collision_margin);
  if (p.material != Material::cloth) sb.setPose(true, sb.m_cfg.kMT > 0.0);
  // Link constants and rest areas now, once (Bullet would otherwise compute the areas from
  // the positions at the first step, which differ between a fresh world and a restored one).
  sb.updateConstants();
  sb.m_bUpdateRtCst = false;
  sb.updateNormals();
  sb.setActivationState(DISABLE_DEACTIVATION);
  world->addSoftBody(soft.get());
}

void BulletSimulator::Impl::build_pieces() {
  const Recipe& rc = *recipe;
  const Params& p = rc.params;
  const int n = num_vertices;
  const Triangles& t = rc.triangles;
  if (const auto hole = first_boundary_edge(t))
    fail("material rigid needs closed pieces; the edge between vertices " +
         std::to_string(hole->first) + " and " + std::to_string(hole->second) +
         " borders a hole (an open surface is cloth)");
  // Connected components (union-find over triangle vertices).
  std::vector<int> parent(static_cast<size_t>(n));
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int v) {
    while (parent[static_cast<size_t>(v)] != v) {
      parent[static_cast<size_t>(v)] = parent[static_cast<size_t>(parent[static_cast<size_t>(v)])];
      v = parent[static_cast<size_t>(v)];
    }
    return v;
  };
  std::vector<char> used(static_cast<size_t>(n), 0);
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    for (int k = 0; k < 3; ++k) {
      used[static_cast<size_t>(t(f, k))] = 1;
      const int a = find(t(f, k)), b = find(t(f, (k + 1) % 3));
      if (a != b) parent[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
    }
  vertex_piece.assign(static_cast<size_t>(n), -1);
  std::map<int, int> root_piece;  // ordered by the smallest vertex id of the piece
  for (int v = 0; v < n; ++v) {
    if (!used[static_cast<size_t>(v)]) continue;
    const int root = find(v);
    auto it = root_piece.find(root);
    if (it == root_piece.end()) {
      it = root_piece.emplace(root, static_cast<int>(pieces.size())).first;
      pieces.emplace_back();
    }
    vertex_piece[static_cast<size_t>(v)] = it->second;
    pieces[static_cast<size_t>(it->second)].vertices.push_back(v);
  }
  std::vector<std::vector<Eigen::Vector3i>> piece_tris(pieces.size());
  for (Eigen::Index f = 0; f < t.rows(); ++f)
    piece_tris[static_cast<size_t>(vertex_piece[static_cast<size_t>(t(f, 0))])].emplace_back(
        t(f, 0), t(f, 1), t(f, 2));
  for (size_t i = 0; i < rc.anchors.size(); ++i) {
    const int a = rc.anchors[i];
    const int pc = vertex_piece[static_cast<size_t>(a)];
    if (pc < 0) continue;
    pieces[static_cast<size_t>(pc)].anchor_rows.push_back(static_cast<int>(i));
  }
  for (size_t b = 0; b < pieces.size(); ++b) {
    Piece& pc = pieces[b];
    const VolumeIntegrals vi = volume_integrals(rc.rest, piece_tris[b]);
    if (!(vi.volume > 0.0))
      fail(
          "material rigid needs each connected piece to be a closed mesh enclosing a positive "
          "volume (counter-clockwise triangles seen from outside); piece " +
          std::to_string(b) + " (containing vertex " + std::to_string(pc.vertices.front()) +
          ") encloses " + std::to_string(vi.volume) + " m^3");
    pc.mass = p.density * vi.volume;
    const Matrix3d inertia = p.density * (vi.second.trace() * Matrix3d::Identity() - vi.second);
    Eigen::SelfAdjointEigenSolver<Matrix3d> es(inertia);
    Matrix3d r = es.eigenvectors();
    if (r.determinant() < 0.0) r.col(2) = -r.col(2);
    pc.inertia = es.eigenvalues();
    pc.rotation0 = r;
    pc.center0 = vi.center;
    pc.local.resize(static_cast<Eigen::Index>(pc.vertices.size()), 3);
    auto shape = std::make_shared<btConvexHullShape>();
    for (size_t k = 0; k < pc.vertices.size(); ++k) {
      const Vector3d l = r.transpose() * (rc.rest.row(pc.vertices[k]).transpose() - vi.center);
      pc.local.row(static_cast<Eigen::Index>(k)) = l.transpose();
      pc.radius2 = std::max(pc.radius2, l.squaredNorm());
      shape->addPoint(to_bt(l), false);
    }
    shape->recalcLocalAabb();
    shape->optimizeConvexHull();
    shape->setMargin(p.collision_margin);
    shape->initializePolyhedralFeatures();
    const btConvexPolyhedron* poly = shape->getConvexPolyhedron();
    if (poly && hull_volume(*poly) > (1.0 + p.hull_tolerance) * vi.volume) {
      pc.concave = true;
      std::map<int, int> local_index;
      for (size_t k = 0; k < pc.vertices.size(); ++k) {
        local_index[pc.vertices[k]] = static_cast<int>(k);
        for (int c = 0; c < 3; ++c)
          pc.mesh_xyz.push_back(pc.local(static_cast<Eigen::Index>(k), c));
      }
      for (const auto& tri : piece_tris[b])
        for (int c = 0; c < 3; ++c) pc.mesh_tris.push_back(local_index.at(tri(c)));
    }
    for (int row : pc.anchor_rows) {
      const int v = rc.anchors[static_cast<size_t>(row)];
      const auto it = std::find(pc.vertices.begin(), pc.vertices.end(), v);
      pc.anchor_local.push_back(static_cast<int>(it - pc.vertices.begin()));
    }
    hulls.push_back(std::move(shape));
  }
}

void BulletSimulator::Impl::build_rigid(const Impl* like) {
  const Recipe& rc = *recipe;
  const Params& p = rc.params;
  if (like) {
    pieces = like->pieces;
    vertex_piece = like->vertex_piece;
    hulls = like->hulls;
  } else {
    build_pieces();
  }
  anchor_pos.resize(static_cast<Eigen::Index>(rc.anchors.size()), 3);
  for (size_t i = 0; i < rc.anchors.size(); ++i)
    anchor_pos.row(static_cast<Eigen::Index>(i)) = rc.rest.row(rc.anchors[i]);
  for (size_t b = 0; b < pieces.size(); ++b) {
    Piece& pc = pieces[b];
    const bool kinematic = !pc.anchor_rows.empty();
    btCollisionShape* shape = hulls[b].get();
    if (pc.concave) {
      auto array = std::make_unique<btTriangleIndexVertexArray>(
          static_cast<int>(pc.mesh_tris.size() / 3), pc.mesh_tris.data(), 3 * sizeof(int),
          static_cast<int>(pc.mesh_xyz.size() / 3), pc.mesh_xyz.data(), 3 * sizeof(double));
      auto mesh = std::make_unique<btGImpactMeshShape>(array.get());
      mesh->setMargin(p.collision_margin);
      mesh->updateBound();
      shape = mesh.get();
      mesh_arrays.push_back(std::move(array));
      mesh_shapes.push_back(std::move(mesh));
    }
    btRigidBody::btRigidBodyConstructionInfo ci(kinematic ? 0.0 : pc.mass, nullptr, shape,
                                                kinematic ? btVector3(0, 0, 0) : to_bt(pc.inertia));
    ci.m_startWorldTransform = btTransform(to_bt_matrix(pc.rotation0), to_bt(pc.center0));
    ci.m_friction = p.friction;
    ci.m_restitution = p.restitution;
    ci.m_linearDamping = p.linear_damping;
    ci.m_angularDamping = p.angular_damping;
    auto body = std::make_unique<btRigidBody>(ci);
    if (kinematic)
      body->setCollisionFlags((body->getCollisionFlags() & ~btCollisionObject::CF_STATIC_OBJECT) |
                              btCollisionObject::CF_KINEMATIC_OBJECT);
    body->setActivationState(DISABLE_DEACTIVATION);
    world->addRigidBody(body.get());
    bodies.push_back(std::move(body));
  }
}

void BulletSimulator::Impl::normalize() {
  // Remove everything and add it back in the build order into a reset broadphase: no pair,
  // collision algorithm or contact manifold survives, and pair creation order is fixed.
  if (soft) world->removeSoftBody(soft.get());
  for (auto it = bodies.rbegin(); it != bodies.rend(); ++it) world->removeRigidBody(it->get());
  for (auto it = planes.rbegin(); it != planes.rend(); ++it) world->removeRigidBody(it->get());
  broadphase->resetPool(dispatcher.get());
  for (auto& p : planes) world->addRigidBody(p.get());
  for (auto& b : bodies) world->addRigidBody(b.get());
  if (soft) {
    // Rebuild the node tree from the current positions (its shape otherwise depends on the
    // history of incremental updates).
    btSoftBody& sb = *soft;
    const btScalar margin = sb.getCollisionShape()->getMargin();
    sb.m_ndbvt.clear();
    for (int i = 0; i < sb.m_nodes.size(); ++i) {
      btSoftBody::Node& nd = sb.m_nodes[i];
      nd.m_leaf = sb.m_ndbvt.insert(btDbvtVolume::FromCR(nd.m_x, margin), &nd);
    }
    sb.updateBounds();
    world->addSoftBody(soft.get());
  }
}

ControlLayout BulletSimulator::Impl::layout() const {
  ControlLayout l;
  if (rigid) {
    l.space = ControlSpace::body_wrench;
    l.num_blocks = static_cast<int>(pieces.size());
    l.block_mass.resize(l.num_blocks);
    l.block_arm.resize(l.num_blocks);
    for (int b = 0; b < l.num_blocks; ++b) {
      const Piece& pc = pieces[static_cast<size_t>(b)];
      l.block_mass(b) = pc.mass;
      // Radius of gyration about the centre of mass: sqrt(trace(I) / (2 m)) is the RMS
      // distance of the mass from the centre.
      l.block_arm(b) = std::sqrt(pc.inertia.sum() / (2.0 * pc.mass));
    }
    l.vertex_block = vertex_piece;
  } else {
    l.space = ControlSpace::vertex_force;
    l.num_blocks = num_vertices;
    l.block_mass = vertex_mass;
    l.vertex_block.resize(static_cast<size_t>(num_vertices));
    std::iota(l.vertex_block.begin(), l.vertex_block.end(), 0);
  }
  return l;
}

Vertices BulletSimulator::Impl::node_positions() const {
  Vertices out(soft->m_nodes.size(), 3);
  for (int i = 0; i < soft->m_nodes.size(); ++i)
    out.row(i) = to_eigen(soft->m_nodes[i].m_x).transpose();
  return out;
}

Vertices BulletSimulator::Impl::positions() const {
  Vertices out(num_vertices, 3);
  if (!rigid) {
    const Vertices x = node_positions();
    for (Eigen::Index i = 0; i < x.rows(); ++i)
      out.row(node_vertex[static_cast<size_t>(i)]) = x.row(i);
    if (sheet) {
      // Attached vertices at their rest offsets from the sheet, anchored ones at their targets.
      const Vertices normals = sheet_normals(*sheet, x);
      for (int v = 0; v < num_vertices; ++v)
        if (vertex_node[static_cast<size_t>(v)] < 0)
          out.row(v) =
              attached_position(*sheet, sheet->attachment[static_cast<size_t>(v)], x, normals)
                  .transpose();
      for (size_t i = 0; i < recipe->anchors.size(); ++i)
        if (vertex_node[static_cast<size_t>(recipe->anchors[i])] < 0)
          out.row(recipe->anchors[i]) = anchor_pos.row(static_cast<Eigen::Index>(i));
    }
    return out;
  }
  out = recipe->rest;  // vertices in no piece stay where they are
  for (size_t b = 0; b < pieces.size(); ++b) {
    const Piece& pc = pieces[b];
    const btTransform& tr = bodies[b]->getWorldTransform();
    const Matrix3d r = to_eigen(tr.getBasis());
    const Vector3d o = to_eigen(tr.getOrigin());
    for (size_t k = 0; k < pc.vertices.size(); ++k)
      out.row(pc.vertices[k]) =
          (r * pc.local.row(static_cast<Eigen::Index>(k)).transpose() + o).transpose();
  }
  // Anchored vertices are exactly at their targets.
  for (size_t i = 0; i < recipe->anchors.size(); ++i)
    out.row(recipe->anchors[i]) = anchor_pos.row(static_cast<Eigen::Index>(i));
  return out;
}

Vertices BulletSimulator::Impl::velocities() const {
  Vertices out = Vertices::Zero(num_vertices, 3);
  if (!rigid) {
    for (int i = 0; i < soft->m_nodes.size(); ++i)
      out.row(node_vertex[static_cast<size_t>(i)]) = to_eigen(soft->m_nodes[i].m_v).transpose();
    // Attached vertices: the velocity of their sheet point (the sheet's turning is left out).
    if (sheet)
      for (int v = 0; v < num_vertices; ++v) {
        if (vertex_node[static_cast<size_t>(v)] >= 0) continue;
        const SheetAttachment& a = sheet->attachment[static_cast<size_t>(v)];
        Vector3d vel = Vector3d::Zero();
        for (int k = 0; k < 3; ++k)
          vel += a.bary[k] * to_eigen(soft->m_nodes[sheet->triangles(a.triangle, k)].m_v);
        out.row(v) = vel.transpose();
      }
    return out;
  }
  const Vertices x = positions();
  for (int v = 0; v < num_vertices; ++v) {
    const int b = vertex_piece[static_cast<size_t>(v)];
    if (b < 0) continue;
    const btRigidBody& body = *bodies[static_cast<size_t>(b)];
    const Vector3d r = x.row(v).transpose() - to_eigen(body.getWorldTransform().getOrigin());
    out.row(v) = (to_eigen(body.getLinearVelocity()) + to_eigen(body.getAngularVelocity()).cross(r))
                     .transpose();
  }
  return out;
}

void BulletSimulator::Impl::step(const StepInput& in) {
  const Recipe& rc = *recipe;
  const Params& p = rc.params;
  if (!(in.dt > 0.0) || !std::isfinite(in.dt))
    fail("step(): dt must be positive and finite (got " + std::to_string(in.dt) + ")");
  // Bullet skips a step shorter than its epsilon (about 2e-16 s) without a word; the anchors'
  // velocities would then come from a division by it.
  if (in.dt / p.substeps < 1e-12) {
    std::ostringstream m;
    m << "step(): a substep of " << in.dt / p.substeps << " s is too short for Bullet (dt " << in.dt
      << " s over " << p.substeps << " substeps; at least 1e-12 s)";
    fail(m.str());
  }
  const ControlLayout l = layout();
  if (in.control.size() != 0 && in.control.size() != l.size())
    fail("step(): control has " + std::to_string(in.control.size()) + " entries, expected " +
         std::to_string(l.size()) + " (or none)");
  if (in.control.size() != 0 && !in.control.allFinite()) fail("step(): control is not finite");
  const Eigen::Index na = static_cast<Eigen::Index>(rc.anchors.size());
  if (in.anchor_targets.rows() != 0 && in.anchor_targets.rows() != na)
    fail("step(): anchor_targets has " + std::to_string(in.anchor_targets.rows()) +
         " rows, expected " + std::to_string(na) + " (or none)");
  if (in.anchor_targets.rows() != 0 && !in.anchor_targets.allFinite())
    fail("step(): anchor_targets are not finite");

  normalize();

  const int substeps = p.substeps;
  const double h = in.dt / substeps;
  const Vertices start = positions();
  Vertices a0(na, 3);
  for (Eigen::Index i = 0; i < na; ++i) a0.row(i) = start.row(rc.anchors[static_cast<size_t>(i)]);
  const Vertices target = in.anchor_targets.rows() != 0 ? in.anchor_targets : a0;
  const bool has_control = in.control.size() != 0;

  // Momentum at the start, for physical_forces().
  std::vector<Vector3d> v_start;
  if (rigid) {
    for (auto& b : bodies) v_start.push_back(to_eigen(b->getLinearVelocity()));
  } else {
    for (int i = 0; i < soft->m_nodes.size(); ++i)
      v_start.push_back(to_eigen(soft->m_nodes[i].m_v));
  }
  // Soft: the control force on each node (a force on an attached vertex acts on the sheet
  // point that carries it, shared by that triangle's nodes), and the anchored nodes' targets:
  // their own anchor's, or the anchors' rigid fit for a node that carries an anchored vertex.
  std::vector<btVector3> node_force;
  bool fitted_anchors = false;
  Eigen::Matrix<double, Eigen::Dynamic, 3> anchor_rest;
  if (!rigid) {
    node_force.assign(static_cast<size_t>(soft->m_nodes.size()), btVector3(0, 0, 0));
    if (has_control)
      for (int v = 0; v < num_vertices; ++v) {
        if (anchored[static_cast<size_t>(v)]) continue;
        const btVector3 f = to_bt(in.control.segment<3>(3 * v));
        const int node = vertex_node[static_cast<size_t>(v)];
        if (node >= 0) {
          node_force[static_cast<size_t>(node)] += f;
          continue;
        }
        const SheetAttachment& a = sheet->attachment[static_cast<size_t>(v)];
        for (int c = 0; c < 3; ++c)
          node_force[static_cast<size_t>(sheet->triangles(a.triangle, c))] += f * a.bary[c];
      }
    for (const NodeAnchor& a : node_anchors) fitted_anchors |= a.row < 0;
    if (fitted_anchors) {
      anchor_rest.resize(na, 3);
      for (Eigen::Index i = 0; i < na; ++i)
        anchor_rest.row(i) = rc.rest.row(rc.anchors[static_cast<size_t>(i)]);
    }
  }
  std::vector<btVector3> node_target(node_anchors.size());

  Vertices sub(na, 3);
  for (int k = 1; k <= substeps; ++k) {
    if (k == substeps)
      sub = target;
    else
      sub = a0 + (static_cast<double>(k) / substeps) * (target - a0);
    if (rigid) {
      for (size_t b = 0; b < pieces.size(); ++b) {
        Piece& pc = pieces[b];
        btRigidBody& body = *bodies[b];
        if (!pc.anchor_rows.empty()) {
          Eigen::Matrix<double, Eigen::Dynamic, 3> lp(pc.anchor_rows.size(), 3),
              q(pc.anchor_rows.size(), 3);
          for (size_t j = 0; j < pc.anchor_rows.size(); ++j) {
            lp.row(static_cast<Eigen::Index>(j)) = pc.local.row(pc.anchor_local[j]);
            q.row(static_cast<Eigen::Index>(j)) = sub.row(pc.anchor_rows[j]);
          }
          Matrix3d r;
          Vector3d o;
          fit_rigid(lp, q, to_eigen(body.getWorldTransform().getBasis()), pc.radius2, &r, &o);
          body.setWorldTransform(btTransform(to_bt_matrix(r), to_bt(o)));
        } else if (has_control) {
          body.applyCentralForce(to_bt(in.control.segment<3>(6 * static_cast<Eigen::Index>(b))));
          body.applyTorque(to_bt(in.control.segment<3>(6 * static_cast<Eigen::Index>(b) + 3)));
        }
      }
    } else {
      btSoftBody& sb = *soft;
      Matrix3d r = Matrix3d::Identity();
      Vector3d o = Vector3d::Zero();
      if (fitted_anchors) fit_rigid(anchor_rest, sub, Matrix3d::Identity(), 1.0, &r, &o);
      for (size_t j = 0; j < node_anchors.size(); ++j) {
        const NodeAnchor& a = node_anchors[j];
        btSoftBody::Node& nd = sb.m_nodes[a.node];
        node_target[j] =
            a.row >= 0
                ? to_bt(sub.row(a.row).transpose())
                : to_bt(r * rc.rest.row(node_vertex[static_cast<size_t>(a.node)]).transpose() + o);
        nd.m_v = (node_target[j] - nd.m_x) / h;
      }
      if (has_control)
        for (int i = 0; i < sb.m_nodes.size(); ++i)
          sb.addForce(node_force[static_cast<size_t>(i)], i);
    }
    world->stepSimulation(h, 0, h);
    if (!rigid) {
      btSoftBody& sb = *soft;
      for (size_t j = 0; j < node_anchors.size(); ++j) {
        btSoftBody::Node& nd = sb.m_nodes[node_anchors[j].node];
        nd.m_v = (node_target[j] - nd.m_q) / h;
        nd.m_x = node_target[j];
      }
    }
  }
  if (rigid || sheet) anchor_pos = target;

  // Physical forces from the change of momentum.
  phys.setZero();
  phys_norm.setZero();
  const Vector3d g = p.gravity;
  if (rigid) {
    for (size_t b = 0; b < pieces.size(); ++b) {
      const Piece& pc = pieces[b];
      if (!pc.anchor_rows.empty()) continue;
      Vector3d f = pc.mass * (to_eigen(bodies[b]->getLinearVelocity()) - v_start[b]) / in.dt;
      if (has_control) f -= in.control.segment<3>(6 * static_cast<Eigen::Index>(b));
      const double share = 1.0 / static_cast<double>(pc.vertices.size());
      const double mag = share * ((pc.mass * g).norm() + (f - pc.mass * g).norm());
      for (int v : pc.vertices) {
        if (anchored[static_cast<size_t>(v)]) continue;
        phys.row(v) = share * f.transpose();
        phys_norm(v) = mag;
      }
    }
  } else {
    // Per free node (at its vertex; attached vertices report none, their mass is carried).
    for (int i = 0; i < soft->m_nodes.size(); ++i) {
      if (!(soft->m_nodes[i].m_im > 0.0)) continue;
      const int v = node_vertex[static_cast<size_t>(i)];
      const double m = carried_mass(i);
      Vector3d f = m * (to_eigen(soft->m_nodes[i].m_v) - v_start[static_cast<size_t>(i)]) / in.dt;
      f -= to_eigen(node_force[static_cast<size_t>(i)]);
      phys.row(v) = f.transpose();
      phys_norm(v) = (m * g).norm() + (f - m * g).norm();
    }
  }
}

size_t BulletSimulator::Impl::state_size() const {
  if (rigid) return 36 * bodies.size() + 3 * static_cast<size_t>(anchor_pos.rows());
  return 15 * static_cast<size_t>(soft->m_nodes.size()) +
         3 * static_cast<size_t>(soft->m_faces.size()) +
         (sheet ? 3 * static_cast<size_t>(anchor_pos.rows()) : 0);
}

SimState BulletSimulator::Impl::save() const {
  SimState s;
  s.values.reserve(state_size());
  auto put = [&](const btVector3& v) {
    s.values.push_back(v.x());
    s.values.push_back(v.y());
    s.values.push_back(v.z());
  };
  auto put_transform = [&](const btTransform& tr) {
    put(tr.getOrigin());
    for (int r = 0; r < 3; ++r) put(tr.getBasis()[r]);
  };
  if (rigid) {
    for (const auto& b : bodies) {
      put_transform(b->getWorldTransform());
      put_transform(b->getInterpolationWorldTransform());
      put(b->getLinearVelocity());
      put(b->getAngularVelocity());
      put(b->getInterpolationLinearVelocity());
      put(b->getInterpolationAngularVelocity());
    }
    for (Eigen::Index i = 0; i < anchor_pos.rows(); ++i)
      for (int c = 0; c < 3; ++c) s.values.push_back(anchor_pos(i, c));
  } else {
    for (int i = 0; i < soft->m_nodes.size(); ++i) {
      const btSoftBody::Node& nd = soft->m_nodes[i];
      put(nd.m_x);
      put(nd.m_q);
      put(nd.m_v);
      put(nd.m_f);
      put(nd.m_n);
    }
    for (int f = 0; f < soft->m_faces.size(); ++f) put(soft->m_faces[f].m_normal);
    if (sheet)
      for (Eigen::Index i = 0; i < anchor_pos.rows(); ++i)
        for (int c = 0; c < 3; ++c) s.values.push_back(anchor_pos(i, c));
  }
  return s;
}

void BulletSimulator::Impl::restore(const SimState& s) {
  if (s.values.size() != state_size())
    fail("restore(): state has " + std::to_string(s.values.size()) + " values, expected " +
         std::to_string(state_size()) + " (a state of another simulator?)");
  size_t at = 0;
  auto get = [&]() {
    const btVector3 v(s.values[at], s.values[at + 1], s.values[at + 2]);
    at += 3;
    return v;
  };
  auto get_transform = [&]() {
    const btVector3 o = get();
    const btVector3 r0 = get(), r1 = get(), r2 = get();
    return btTransform(
        btMatrix3x3(r0.x(), r0.y(), r0.z(), r1.x(), r1.y(), r1.z(), r2.x(), r2.y(), r2.z()), o);
  };
  if (rigid) {
    for (auto& b : bodies) {
      const btTransform tr = get_transform();
      const btTransform itr = get_transform();
      b->setWorldTransform(tr);
      b->setInterpolationWorldTransform(itr);
      b->setLinearVelocity(get());
      b->setAngularVelocity(get());
      b->setInterpolationLinearVelocity(get());
      b->setInterpolationAngularVelocity(get());
      b->updateInertiaTensor();
      b->clearForces();
    }
    for (Eigen::Index i = 0; i < anchor_pos.rows(); ++i)
      for (int c = 0; c < 3; ++c) anchor_pos(i, c) = s.values[at++];
  } else {
    for (int i = 0; i < soft->m_nodes.size(); ++i) {
      btSoftBody::Node& nd = soft->m_nodes[i];
      nd.m_x = get();
      nd.m_q = get();
      nd.m_v = get();
      nd.m_f = get();
      nd.m_n = get();
    }
    for (int f = 0; f < soft->m_faces.size(); ++f) soft->m_faces[f].m_normal = get();
    if (sheet)
      for (Eigen::Index i = 0; i < anchor_pos.rows(); ++i)
        for (int c = 0; c < 3; ++c) anchor_pos(i, c) = s.values[at++];
  }
}

// ----- BulletSimulator ---------------------------------------------------------------------

namespace {

std::shared_ptr<const Recipe> make_recipe(const Mesh& mesh, const Vertices& positions,
                                          std::vector<int> anchors, const Params& params) {
  params.validate();
  const int n = static_cast<int>(positions.rows());
  if (n == 0) fail("the mesh has no vertices");
  if (mesh.num_vertices() != 0 && mesh.num_vertices() != n)
    fail("positions have " + std::to_string(n) + " rows but the mesh has " +
         std::to_string(mesh.num_vertices()) + " vertices");
  if (!positions.allFinite()) fail("positions are not finite");
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k)
      if (mesh.triangles(f, k) < 0 || mesh.triangles(f, k) >= n)
        fail("triangle " + std::to_string(f) + " has vertex index " +
             std::to_string(mesh.triangles(f, k)) + " out of range [0, " + std::to_string(n) + ")");
  std::sort(anchors.begin(), anchors.end());
  for (size_t i = 0; i < anchors.size(); ++i) {
    if (anchors[i] < 0 || anchors[i] >= n)
      fail("anchor " + std::to_string(anchors[i]) + " out of range [0, " + std::to_string(n) + ")");
    if (i > 0 && anchors[i] == anchors[i - 1])
      fail("anchor " + std::to_string(anchors[i]) + " given twice");
  }
  auto r = std::make_shared<Recipe>();
  r->triangles = mesh.triangles;
  r->rest = positions;
  r->anchors = std::move(anchors);
  r->params = params;
  return r;
}

}  // namespace

BulletSimulator::BulletSimulator(const Mesh& mesh, const Vertices& positions,
                                 std::vector<int> anchors, const Params& params)
    : m_impl(std::make_unique<Impl>(make_recipe(mesh, positions, std::move(anchors), params))) {}

BulletSimulator::BulletSimulator(const Mesh& mesh, std::vector<int> anchors, const Params& params)
    : BulletSimulator(mesh, mesh.vertices, std::move(anchors), params) {}

BulletSimulator::BulletSimulator() = default;
BulletSimulator::~BulletSimulator() = default;

int BulletSimulator::num_vertices() const {
  return m_impl->num_vertices;
}
Vertices BulletSimulator::positions() const {
  return m_impl->positions();
}
Vertices BulletSimulator::velocities() const {
  return m_impl->velocities();
}
ControlLayout BulletSimulator::control_layout() const {
  return m_impl->layout();
}
std::vector<int> BulletSimulator::anchors() const {
  return m_impl->recipe->anchors;
}
void BulletSimulator::step(const StepInput& in) {
  m_impl->step(in);
}
Vertices BulletSimulator::physical_forces() const {
  return m_impl->phys;
}
Eigen::VectorXd BulletSimulator::physical_force_magnitudes() const {
  return m_impl->phys_norm;
}
SimState BulletSimulator::save() const {
  return m_impl->save();
}
void BulletSimulator::restore(const SimState& state) {
  m_impl->restore(state);
}

std::unique_ptr<Simulator> BulletSimulator::clone() const {
  std::unique_ptr<BulletSimulator> copy(new BulletSimulator());
  copy->m_impl = std::make_unique<Impl>(m_impl->recipe, m_impl.get());
  copy->m_impl->restore(m_impl->save());
  copy->m_impl->phys = m_impl->phys;
  copy->m_impl->phys_norm = m_impl->phys_norm;
  return copy;
}

const Params& BulletSimulator::params() const {
  return m_impl->recipe->params;
}

int BulletSimulator::num_layer_ties() const {
  return m_impl->layer_ties;
}

int BulletSimulator::num_nodes() const {
  return m_impl->rigid ? 0 : m_impl->soft->m_nodes.size();
}

std::vector<int> BulletSimulator::node_vertices() const {
  return m_impl->rigid ? std::vector<int>{} : m_impl->node_vertex;
}

int BulletSimulator::num_bodies() const {
  return m_impl->rigid ? static_cast<int>(m_impl->pieces.size()) : 1;
}

Eigen::VectorXd BulletSimulator::masses() const {
  if (!m_impl->rigid) {
    Eigen::VectorXd m = m_impl->vertex_mass;
    for (int a : m_impl->recipe->anchors) m(a) = 0.0;
    return m;
  }
  Eigen::VectorXd m(static_cast<Eigen::Index>(m_impl->pieces.size()));
  for (size_t b = 0; b < m_impl->pieces.size(); ++b)
    m(static_cast<Eigen::Index>(b)) = m_impl->pieces[b].mass;
  return m;
}

Vertices BulletSimulator::centers_of_mass() const {
  if (m_impl->rigid) {
    Vertices c(static_cast<Eigen::Index>(m_impl->bodies.size()), 3);
    for (size_t b = 0; b < m_impl->bodies.size(); ++b)
      c.row(static_cast<Eigen::Index>(b)) =
          to_eigen(m_impl->bodies[b]->getWorldTransform().getOrigin()).transpose();
    return c;
  }
  const Eigen::VectorXd m = masses();
  const Vertices x = positions();
  Vertices c(1, 3);
  c.row(0) = (x.transpose() * m).transpose() / std::max(m.sum(), 1e-300);
  return c;
}

}  // namespace pbve::bullet
