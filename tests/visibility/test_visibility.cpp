// Per-triangle visibility on geometry with closed-form answers.

#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/testing/shapes.hpp"
#include "pbve/visibility/visibility.hpp"

namespace pbve {
namespace {

using testing::concatenate;
using testing::make_icosphere;
using testing::make_plate;
using testing::Shape;

TEST(SamplePattern, SquareCountsOfInteriorPointsWithTheCentroid) {
  for (int requested : {1, 2, 4, 5, 9, 16, 25}) {
    const Eigen::MatrixX3d p = triangle_sample_pattern(requested);
    const int k = static_cast<int>(std::floor(std::sqrt(requested)));
    ASSERT_EQ(p.rows(), k * k) << requested;
    for (Eigen::Index i = 0; i < p.rows(); ++i) {
      EXPECT_NEAR(p.row(i).sum(), 1.0, 1e-15);
      EXPECT_GT(p.row(i).minCoeff(), 0.0);  // strictly inside
    }
    bool has_centroid = false;
    for (Eigen::Index i = 0; i < p.rows(); ++i)
      has_centroid |= (p.row(i).array() - 1.0 / 3.0).abs().maxCoeff() < 1e-12;
    EXPECT_EQ(has_centroid, k % 3 != 0) << k;
  }
}

// A plate hinged on a vertical axis through q = (qx, 0, qz), extending from the axis along
// u(theta) = (cos theta, 0, sin theta). Its normal is (sin theta, 0, -cos theta), so
// <n, c> = <n, q> = qx sin theta - qz cos theta: the plate turns its back to the camera
// exactly when the camera centre enters its plane, at tan theta* = qz / qx.
Shape hinged_plate(double theta, const Eigen::Vector3d& q) {
  const Eigen::Vector3d u(std::cos(theta), 0.0, std::sin(theta));
  return make_plate(q + Eigen::Vector3d(0.0, 0.2, 0.0), 0.6 * u, {0.0, -0.4, 0.0}, 6, 4);
}

TEST(Visibility, RotatingPlateFlipsExactlyAtTheComputedAngle) {
  const Camera camera;
  const Eigen::Vector3d q(-0.5, 0.0, 2.0);
  const double theta_star = std::numbers::pi - std::atan(4.0);  // tan theta* = 2 / -0.5
  VisibilityOptions back_face_only;
  back_face_only.occlusion = false;
  // Back-face test alone is exact in double precision: 1e-9 rad either side suffices.
  for (double delta : {1e-9, 1e-3, 0.3}) {
    const Shape before = hinged_plate(theta_star - delta, q);
    const Shape after = hinged_plate(theta_star + delta, q);
    const auto vb = compute_visibility(before.vertices, before.triangles, camera, back_face_only);
    const auto va = compute_visibility(after.vertices, after.triangles, camera, back_face_only);
    EXPECT_EQ(vb.visible_count(), before.triangles.rows()) << delta;
    EXPECT_EQ(va.visible_count(), 0) << delta;
    // s = <n, q> / (|n| |c|) changes sign with the analytic <n, q>.
    for (Eigen::Index j = 0; j < vb.facing.size(); ++j) {
      EXPECT_LT(vb.facing[j], 0.0);
      EXPECT_GT(va.facing[j], 0.0);
    }
  }
  // With occlusion the rays to the sample points must still find the plate itself. Near the
  // edge-on pose the single-precision hit distance degrades like 1e-7 / sin(angle to the ray),
  // so test 1e-2 rad away, where that error (~1e-5) is below the 1e-4 depth tolerance.
  const double delta = 1e-2;
  const Shape before = hinged_plate(theta_star - delta, q);
  const Shape after = hinged_plate(theta_star + delta, q);
  RayScene scene(before.vertices, before.triangles);
  const auto vb = compute_visibility(scene, camera);
  EXPECT_EQ(vb.visible_count(), before.triangles.rows());
  EXPECT_EQ(vb.visible_fraction.minCoeff(), 1.0);
  EXPECT_GT(vb.rays_cast, 0);
  const auto va = compute_visibility(scene, after.vertices, camera);
  EXPECT_EQ(va.visible_count(), 0);
  // Facing the camera squarely (theta = 0): s_j = -qz / |c_j| for every triangle.
  const Shape square = hinged_plate(0.0, q);
  const Eigen::VectorXd s = facing_values(square.vertices, square.triangles);
  for (Eigen::Index j = 0; j < s.size(); ++j) {
    const Eigen::Vector3d c =
        (square.vertices.row(square.triangles(j, 0)) + square.vertices.row(square.triangles(j, 1)) +
         square.vertices.row(square.triangles(j, 2)))
            .transpose() /
        3.0;
    EXPECT_NEAR(s[j], -2.0 / c.norm(), 1e-14);
  }
}

// Back plate at depth 4, x, y in [-0.4, 0.4], 8 x 8 cells; front plate at depth 2 covering
// x in [-0.3, 0] and y in [-0.25, 0.25]: seen from the origin it hides exactly x < 0 of the
// back plate (the rays scale by 2), a cell boundary, so every back triangle is either fully
// hidden or fully seen and the hidden area fraction is exactly 1/2.
Shape plates_scene() {
  const Shape back = make_plate({-0.4, 0.4, 4.0}, {0.8, 0.0, 0.0}, {0.0, -0.8, 0.0}, 8, 8);
  const Shape front = make_plate({-0.3, 0.25, 2.0}, {0.3, 0.0, 0.0}, {0.0, -0.5, 0.0}, 3, 5);
  return concatenate(back, front);
}

TEST(Visibility, ACameraThatIsNotValidIsAnErrorNotAnAbort) {
  // A zero or non-finite focal length gives rays Embree aborts the process on, and so does one
  // so short that the rays through the image's edges have components beyond 1.844e18 (320.5 /
  // 1e-20 = 3.2e22 is finite in float, but beyond Embree's range).
  const Shape s = plates_scene();
  RayScene scene(s.vertices, s.triangles);
  for (const double fx : {0.0, std::nan(""), 1e-40, 1e-20, 0.99 * 320.5 / 1.844e18}) {
    Camera camera;
    camera.fx = fx;
    EXPECT_THROW(compute_visibility(scene, camera), InputError) << fx;
    EXPECT_THROW(scene.cast_primary(camera, 1), InputError) << fx;
  }
  // A principal point far outside the image (allowed here: a camera for a part of an image)
  // moves the edges as far from it.
  Camera far;
  far.cx = 1e30;
  EXPECT_THROW(scene.cast_primary(far, 1), InputError);
  EXPECT_THROW(compute_visibility(scene, far), InputError);
  // Just above the least focal length (the default camera's left edge is 320.5 px from its
  // principal point) every ray through the image is cast. Only column 320 (u = cx) looks ahead;
  // the others run almost along the image plane and miss: the back plate spans rows 180 to 300.
  Camera shortest;
  shortest.fx = 1.01 * 320.5 / 1.844e18;
  const PrimaryHits hits = scene.cast_primary(shortest, 1);
  EXPECT_GT(hits.hit_count(), 100);
  for (int y = 0; y < hits.height; ++y) {
    for (int x = 0; x < hits.width; ++x) {
      if (hits.triangle[static_cast<size_t>(y) * hits.width + x] >= 0) {
        ASSERT_EQ(x, 320) << y;
      }
    }
  }
  EXPECT_THROW(scene.cast_primary(Camera{}, 1 << 20), InputError);  // too many rays
  Triangles bad = s.triangles;
  bad(0, 2) = 100000000;
  EXPECT_THROW(projected_areas_px(s.vertices, bad, Camera{}), std::invalid_argument);
}

TEST(Visibility, PlateBehindPlateIsHiddenWhereTheyOverlap) {
  const Camera camera;
  const Shape scene_shape = plates_scene();
  RayScene scene(scene_shape.vertices, scene_shape.triangles);
  const auto vis = compute_visibility(scene, camera);
  const int back_count = 128;
  double hidden_area = 0.0, back_area = 0.0;
  for (int j = 0; j < back_count; ++j) {
    const double x = (scene_shape.vertices.row(scene_shape.triangles(j, 0)) +
                      scene_shape.vertices.row(scene_shape.triangles(j, 1)) +
                      scene_shape.vertices.row(scene_shape.triangles(j, 2)))(0) /
                     3.0;
    EXPECT_EQ(vis.visible_fraction[j], x < 0.0 ? 0.0 : 1.0) << j;
    EXPECT_EQ(vis.visible[j], x < 0.0 ? 0 : 1) << j;
    hidden_area += (1.0 - vis.visible_fraction[j]) * vis.projected_area_px[j];
    back_area += vis.projected_area_px[j];
  }
  EXPECT_NEAR(hidden_area / back_area, 0.5, 1e-12);
  // The back plate projects to 0.8 * 600 / 4 = 120 px square.
  EXPECT_NEAR(back_area, 120.0 * 120.0, 1e-9);
  for (Eigen::Index j = back_count; j < scene_shape.triangles.rows(); ++j)
    EXPECT_EQ(vis.visible[static_cast<size_t>(j)], 1);

  // The paper's back-face-only test sees every front-facing triangle, hidden or not.
  VisibilityOptions back_face_only;
  back_face_only.occlusion = false;
  const auto bf = compute_visibility(scene, camera, back_face_only);
  EXPECT_EQ(bf.visible_count(), scene_shape.triangles.rows());
  EXPECT_EQ(bf.rays_cast, 0);
  EXPECT_EQ(vis.visible_count(), scene_shape.triangles.rows() - back_count / 2);
}

TEST(Visibility, PartlyHiddenTriangleFractionMatchesTheOverlapArea) {
  // Back triangle a = (0, 0), b = (0, s), c = (s, 0) at depth 4 (s = 0.4), front-facing. An
  // occluder at depth 2 hides x < s / 2 of it. The seen part {x > s/2} is a triangle with half
  // the legs: 1/4 of the area. It is bounded by a line of the k x k sample lattice for even k,
  // so the k^2 sub-triangle centroids give exactly 1/4.
  Shape back;
  back.vertices.resize(3, 3);
  back.vertices << 0.0, 0.0, 4.0, 0.0, 0.4, 4.0, 0.4, 0.0, 4.0;
  back.triangles.resize(1, 3);
  back.triangles << 0, 1, 2;
  const Shape front = make_plate({-0.5, 0.5, 2.0}, {0.6, 0.0, 0.0}, {0.0, -1.0, 0.0}, 1, 1);
  const Shape both = concatenate(back, front);
  RayScene scene(both.vertices, both.triangles);
  for (int samples : {4, 16, 64, 256}) {
    VisibilityOptions options;
    options.samples_per_triangle = samples;
    const auto vis = compute_visibility(scene, Camera{}, options);
    EXPECT_DOUBLE_EQ(vis.visible_fraction[0], 0.25) << samples;
    EXPECT_EQ(vis.visible[0], 0) << samples;  // below the default 0.5 threshold
    options.min_visible_fraction = 0.25;
    EXPECT_EQ(compute_visibility(scene, Camera{}, options).visible[0], 1) << samples;
  }
}

// 3-D triangle areas.
Eigen::VectorXd area_of(const Shape& shape) {
  Eigen::VectorXd area(shape.triangles.rows());
  for (Eigen::Index j = 0; j < area.size(); ++j) {
    const Eigen::Vector3d a = shape.vertices.row(shape.triangles(j, 0)).transpose();
    const Eigen::Vector3d b = shape.vertices.row(shape.triangles(j, 1)).transpose();
    const Eigen::Vector3d c = shape.vertices.row(shape.triangles(j, 2)).transpose();
    area[j] = 0.5 * (b - a).cross(c - a).norm();
  }
  return area;
}

TEST(Visibility, SphereShowsASmallerCapThanAHemisphere) {
  // Sphere of radius r at distance d: a tangent plane at unit normal m faces the camera iff
  // <m, centre> < -r, i.e. the visible cap has half-angle acos(r / d) and area fraction
  // (1 - r / d) / 2 of the sphere. Triangles of a level-4 icosphere (5120 triangles, edge
  // ~0.069 r) straddle the cap boundary in a band of area ~ sin(alpha) * h / 2 ~ 3% of the
  // sphere; misclassifications in that band largely cancel, and the triangles' planes lie at
  // distance slightly below r, which raises the fraction by O(h^2). A 1% absolute tolerance
  // leaves room for both.
  const double r = 1.0;
  for (double d : {2.0, 4.0, 1000.0}) {
    const Shape sphere = make_icosphere(4, r, {0.0, 0.0, d});
    Camera camera;
    camera.fx = camera.fy = 100.0 * d;  // keep the sphere inside the image
    RayScene scene(sphere.vertices, sphere.triangles);
    VisibilityOptions back_face_only;
    back_face_only.occlusion = false;
    const auto bf = compute_visibility(scene, camera, back_face_only);
    const auto oc = compute_visibility(scene, camera);
    const Eigen::VectorXd area = area_of(sphere);
    double front_area = 0.0;
    for (Eigen::Index j = 0; j < area.size(); ++j) front_area += bf.visible[j] * area[j];
    const double expected = (1.0 - r / d) / 2.0;
    EXPECT_NEAR(front_area / area.sum(), expected, 0.01) << d;
    EXPECT_NEAR(double(bf.visible_count()) / sphere.triangles.rows(), expected, 0.01) << d;
    // Convex: nothing front-facing is hidden.
    EXPECT_EQ(oc.visible, bf.visible) << d;
  }
}

TEST(Visibility, TrianglesBehindTheCameraOrOutsideTheImageAreNotVisible) {
  const Camera camera;
  // Facing the camera geometrically (det < 0) but behind it: z < 0.
  const Shape behind = make_plate({-0.4, 0.4, -2.0}, {0.8, 0.0, 0.0}, {0.0, -0.8, 0.0}, 1, 1);
  VisibilityOptions options;
  options.occlusion = false;
  const auto vb = compute_visibility(behind.vertices, behind.triangles, camera, options);
  EXPECT_EQ(vb.visible_count(), 0);
  EXPECT_EQ(vb.projected_area_px.maxCoeff(), 0.0);
  // Far to the right of the image (x / z = 2 -> pixel 1520).
  const Shape outside = make_plate({3.6, 0.4, 2.0}, {0.8, 0.0, 0.0}, {0.0, -0.8, 0.0}, 1, 1);
  EXPECT_EQ(
      compute_visibility(outside.vertices, outside.triangles, camera, options).visible_count(), 0);
  options.clip_to_image = false;
  EXPECT_EQ(
      compute_visibility(outside.vertices, outside.triangles, camera, options).visible_count(), 2);
  options.occlusion = true;
  EXPECT_THROW(compute_visibility(outside.vertices, outside.triangles, camera, options),
               std::invalid_argument);
}

TEST(Visibility, ProjectedAreaMatchesTheProjectedCorners) {
  // A tilted quad: its projection is the quadrilateral of the projected corners (shoelace).
  const Camera camera;
  const Shape plate = make_plate({-0.3, 0.2, 2.0}, {0.5, 0.0, 0.4}, {0.1, -0.45, 0.2}, 1, 1);
  const Eigen::VectorXd area = projected_areas_px(plate.vertices, plate.triangles, camera);
  const int corners[4] = {0, 1, 3, 2};
  double shoelace = 0.0;
  for (int i = 0; i < 4; ++i) {
    const Eigen::Vector2d p = camera.project(plate.vertices.row(corners[i]).transpose());
    const Eigen::Vector2d q = camera.project(plate.vertices.row(corners[(i + 1) % 4]).transpose());
    shoelace += p.x() * q.y() - q.x() * p.y();
  }
  EXPECT_NEAR(area.sum(), std::abs(shoelace) / 2.0, 1e-9 * area.sum());
}

}  // namespace
}  // namespace pbve
