#pragma once
// A cloth board for the control tests and benchmark: a sheet of mass_spring cloth facing the
// camera, clamped along its left edge (two vertex columns), swung by turning the clamped edge
// about its own (vertical) axis. The input footage shows a rigid board turning the same way,
// so its front is always observed and its back never is; without control the cloth lags and
// overshoots the turn until its back faces the camera.

#include <algorithm>
#include <cmath>
#include <memory>
#include <numbers>
#include <vector>

#include <Eigen/Geometry>

#include "pbve/control/optimizer.hpp"
#include "pbve/core/camera.hpp"
#include "pbve/mass_spring/mass_spring.hpp"
#include "pbve/testing/shapes.hpp"
#include "pbve/visibility/metric.hpp"
#include "pbve/visibility/ray_scene.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve::test {

struct ClothScene {
  int nu = 16, nv = 12;         ///< cells along x (away from the clamp) and y
  double width = 0.32;          ///< metres, along x
  double height = 0.24;         ///< metres, along y (down)
  double depth = 1.0;           ///< distance of the board from the camera, metres
  double amplitude_deg = 70.0;  ///< turn of the clamped edge: amplitude * sin(2 pi t / period)
  double period_s = 1.2;        ///< seconds
  int frames = 36;              ///< at 30 frames per second
  double fps = 30.0;
  double bend_stiffness = 1e-2;  ///< N*m (stiffer than the cloth preset: a floppy board)
  int substeps = 5;              ///< backward Euler substeps per frame
  mass_spring::LinearSolver linear_solver = mass_spring::LinearSolver::automatic;

  Camera camera;             ///< 640 x 480, f = 600 px
  Mesh sheet;                ///< one-sided sheet, front (normal -z) towards the camera
  std::vector<int> anchors;  ///< the two left vertex columns
  Triangles two_sided;       ///< front triangles then the same reversed (the back side)

  ClothScene() { build(); }
  explicit ClothScene(int nu_, int nv_) : nu(nu_), nv(nv_) { build(); }

  void build() {
    // make_plate's normals are U x V; U = -x, V = +y gives -z (towards the camera) with the
    // clamped edge at x = +width/2... so mirror: corner at the right, U along -x.
    const auto plate =
        testing::make_plate(Eigen::Vector3d(0.5 * width, -0.5 * height, depth),
                            Eigen::Vector3d(-width, 0, 0), Eigen::Vector3d(0, height, 0), nu, nv);
    sheet.vertices = plate.vertices;
    sheet.triangles = plate.triangles;
    sheet.triangle_part.assign(static_cast<size_t>(plate.triangles.rows()), 0);
    sheet.part_names = {"default"};
    sheet.interior.assign(static_cast<size_t>(plate.triangles.rows()), 0);
    anchors.clear();
    // Columns i = nu and nu - 1 sit at x = -width/2 (the left edge in the image).
    for (int j = 0; j <= nv; ++j)
      for (int i : {nu - 1, nu}) anchors.push_back(j * (nu + 1) + i);
    std::sort(anchors.begin(), anchors.end());
    const Eigen::Index nf = sheet.triangles.rows();
    two_sided.resize(2 * nf, 3);
    two_sided.topRows(nf) = sheet.triangles;
    for (Eigen::Index f = 0; f < nf; ++f)
      two_sided.row(nf + f) << sheet.triangles(f, 0), sheet.triangles(f, 2), sheet.triangles(f, 1);
  }

  int num_vertices() const { return static_cast<int>(sheet.vertices.rows()); }
  double angle(int frame) const {
    return amplitude_deg * std::numbers::pi / 180.0 *
           std::sin(2.0 * std::numbers::pi * frame / (fps * period_s));
  }
  /// The rigid board of input frame `frame` (0 = rest): turned about the clamped edge's axis.
  Vertices input_positions(int frame) const {
    const Eigen::Vector3d axis_point(-0.5 * width, 0.0, depth);
    const Eigen::Matrix3d r = Eigen::AngleAxisd(angle(frame), Eigen::Vector3d::UnitY()).matrix();
    Vertices x = sheet.vertices;
    for (Eigen::Index i = 0; i < x.rows(); ++i)
      x.row(i) = (r * (x.row(i).transpose() - axis_point) + axis_point).transpose();
    return x;
  }
  Vertices anchor_targets(int frame) const {
    const Vertices x = input_positions(frame);
    Vertices a(static_cast<Eigen::Index>(anchors.size()), 3);
    for (size_t k = 0; k < anchors.size(); ++k)
      a.row(static_cast<Eigen::Index>(k)) = x.row(anchors[k]);
    return a;
  }
  /// v_j of the one-sided sheet in input frame `frame` (back-face test and occlusion).
  std::vector<std::uint8_t> observed(int frame) const {
    RayScene scene(input_positions(frame), sheet.triangles);
    return compute_visibility(scene, camera).visible;
  }
  /// The optimizer's view: the front triangles unobserved where the input does not show them,
  /// the back side never observed.
  ControlFrameInput control_input(int frame) const {
    ControlFrameInput in;
    in.dt = 1.0 / fps;
    in.anchor_targets = anchor_targets(frame);
    const auto v = observed(frame);
    in.unobserved.assign(2 * v.size(), 1);
    for (size_t j = 0; j < v.size(); ++j) in.unobserved[j] = v[j] ? 0 : 1;
    return in;
  }
  std::unique_ptr<mass_spring::MassSpringSimulator> simulator() const {
    auto p = mass_spring::Params::preset(mass_spring::Material::cloth);
    p.bend_stiffness = bend_stiffness;
    p.substeps = substeps;
    p.linear_solver = linear_solver;
    return std::make_unique<mass_spring::MassSpringSimulator>(sheet, anchors, p);
  }
  /// The paper's Figure 7 measure on the simulated sheet: area showing the never-observed back
  /// side or a front triangle not observed in input frame `frame`, percent of the object area.
  double violation_pct(const Vertices& simulated, int frame) const {
    RayScene scene(simulated, sheet.triangles);
    MetricOptions m;
    m.back_faces_violate = true;
    return violation_metric(scene, camera, observed(frame), sheet.interior, m).violation_pct;
  }
};

}  // namespace pbve::test
