// RayScene: hits, barycentrics, refit and rebuild, errors.

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/testing/shapes.hpp"
#include "pbve/visibility/ray_scene.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

using testing::make_plate;

Camera small_camera() {
  return test::centred_camera(160, 120, 200.0);
}

TEST(RayScene, EmptySceneMissesEverything) {
  RayScene scene;
  const PrimaryHits hits = scene.cast_primary(small_camera(), 1);
  EXPECT_EQ(hits.width, 160);
  EXPECT_EQ(hits.height, 120);
  EXPECT_EQ(hits.hit_count(), 0);
}

TEST(RayScene, PrimaryHitsReconstructThePointSeenAtEachSample) {
  const Camera camera = small_camera();
  // A tilted plate filling part of the image.
  const auto plate = make_plate({-0.3, -0.2, 1.5}, {0.6, 0.0, 0.3}, {0.0, 0.4, 0.1}, 5, 4);
  RayScene scene(plate.vertices, plate.triangles);
  const PrimaryHits hits = scene.cast_primary(camera, 2);
  ASSERT_EQ(hits.triangle.size(), size_t(hits.width) * hits.height);
  int checked = 0;
  for (int y = 0; y < hits.height; ++y) {
    for (int x = 0; x < hits.width; ++x) {
      const size_t i = size_t(y) * hits.width + x;
      const int t = hits.triangle[i];
      if (t < 0) continue;
      ASSERT_LT(t, plate.triangles.rows());
      const Eigen::Vector3d a = plate.vertices.row(plate.triangles(t, 0)).transpose();
      const Eigen::Vector3d b = plate.vertices.row(plate.triangles(t, 1)).transpose();
      const Eigen::Vector3d c = plate.vertices.row(plate.triangles(t, 2)).transpose();
      const Eigen::Vector3d p = (1.0 - hits.u[i] - hits.v[i]) * a + hits.u[i] * b + hits.v[i] * c;
      // Single-precision intersection: the reconstructed point projects back onto the sample
      // within ~1e-7 relative of the coordinates, far below 1e-3 px at this scale.
      EXPECT_NEAR((camera.project(p) - hits.sample_position(x, y)).norm(), 0.0, 1e-3);
      EXPECT_NEAR(hits.depth[i], p.z(), 1e-5);
      ++checked;
    }
  }
  EXPECT_GT(checked, 1000);
}

TEST(RayScene, RefitFollowsMovedVerticesLikeARebuild) {
  const Camera camera = small_camera();
  const auto plate = make_plate({-0.2, -0.2, 2.0}, {0.4, 0.0, 0.0}, {0.0, 0.4, 0.0}, 4, 4);
  RayScene scene(plate.vertices, plate.triangles);
  const std::int64_t before = scene.cast_primary(camera).hit_count();
  // Move the plate closer: it covers (2 / 1)^2 = 4 times as many pixels.
  Vertices moved = plate.vertices;
  moved.col(2).array() -= 1.0;
  scene.update(moved);
  const PrimaryHits refit = scene.cast_primary(camera);
  RayScene rebuilt(moved, plate.triangles);
  const PrimaryHits fresh = rebuilt.cast_primary(camera);
  EXPECT_EQ(refit.triangle, fresh.triangle);
  // 0.4 units at depth 2 (then 1) with f = 200 px: 40 x 40 px (then 80 x 80 px). The principal
  // point (79.5, 59.5) puts the plate's edges half-way between pixel centres, so the counts
  // are exact.
  EXPECT_EQ(before, 40 * 40);
  EXPECT_EQ(refit.hit_count(), 80 * 80);
  scene.update(plate.vertices, UpdateMode::rebuild);
  EXPECT_EQ(scene.cast_primary(camera).hit_count(), before);
  EXPECT_EQ(scene.vertices(), plate.vertices);
}

TEST(RayScene, IntersectAndOcclusionQueries) {
  const auto plate = make_plate({-1.0, -1.0, 2.0}, {2.0, 0.0, 0.0}, {0.0, 2.0, 0.0}, 2, 2);
  RayScene scene(plate.vertices, plate.triangles);
  Eigen::MatrixX3d origins = Eigen::MatrixX3d::Zero(3, 3);
  Eigen::MatrixX3d directions(3, 3);
  directions << 0.1, 0.2, 1.0,  // hits at t = 2
      0.0, 0.0, -1.0,           // points away
      5.0, 0.0, 1.0;            // passes beside the plate
  const auto hits = scene.intersect(origins, directions);
  ASSERT_EQ(hits.size(), 3u);
  EXPECT_GE(hits[0].triangle, 0);
  EXPECT_NEAR(hits[0].t, 2.0f, 1e-5f);
  EXPECT_EQ(hits[1].triangle, -1);
  EXPECT_EQ(hits[2].triangle, -1);
  Eigen::MatrixX3d targets(2, 3);
  targets << 0.0, 0.0, 4.0,  // behind the plate
      0.0, 0.0, 1.0;         // in front of it
  const auto occluded = scene.occluded_from_origin(targets, 0.999);
  EXPECT_EQ(occluded[0], 1);
  EXPECT_EQ(occluded[1], 0);
}

TEST(RayScene, RejectsBadInput) {
  const auto plate = make_plate({-1.0, -1.0, 2.0}, {2.0, 0.0, 0.0}, {0.0, 2.0, 0.0}, 1, 1);
  RayScene scene(plate.vertices, plate.triangles);
  EXPECT_THROW(scene.update(Vertices::Zero(3, 3)), InputError);
  Vertices bad = plate.vertices;
  bad(1, 2) = std::nan("");
  EXPECT_THROW(scene.update(bad), InputError);
  Triangles out_of_range = plate.triangles;
  out_of_range(0, 1) = 17;
  EXPECT_THROW(RayScene(plate.vertices, out_of_range), InputError);
  EXPECT_THROW(scene.cast_primary(small_camera(), 0), InputError);
}

// The InputError message of `query()`, or "" when it does not throw one.
template <class Query>
std::string input_error(const Query& query) {
  try {
    query();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

// Embree aborts the process on a ray with a component that is NaN, infinite or finite beyond
// 1.844e18, and on a NaN ray parameter: the queries refuse them, naming the query, the ray and
// its value, and answer the next valid query as before.
TEST(RayScene, RaysEmbreeCannotTraceAreAnErrorNotAnAbort) {
  const auto plate = make_plate({-1.0, -1.0, 2.0}, {2.0, 0.0, 0.0}, {0.0, 2.0, 0.0}, 2, 2);
  RayScene scene(plate.vertices, plate.triangles);
  const int n = 40;  // three packets of 16
  const Eigen::MatrixX3d origins = Eigen::MatrixX3d::Zero(n, 3);
  Eigen::MatrixX3d directions(n, 3);
  directions.rowwise() = Eigen::RowVector3d(0.1, 0.2, 1.0);  // hits at t = 2
  const Eigen::MatrixX3d targets = 4.0 * directions;         // behind the plate
  const double inf = std::numeric_limits<double>::infinity();
  for (const double bad : {std::nan(""), inf, -inf, 1e20, -2e18}) {
    SCOPED_TRACE(bad);
    Eigen::MatrixX3d o = origins, d = directions, t = targets;
    o(17, 1) = bad;
    o(35, 0) = bad;  // a later one: the first is named
    std::string what = input_error([&] { scene.intersect(o, directions); });
    EXPECT_NE(what.find("intersect(): ray 17: origin (0, "), std::string::npos) << what;
    d(33, 2) = bad;
    what = input_error([&] { scene.intersect(origins, d); });
    EXPECT_NE(what.find("intersect(): ray 33: direction (0.1, 0.2, "), std::string::npos) << what;
    t(21, 0) = bad;
    what = input_error([&] { scene.occluded_from_origin(t, 0.999); });
    EXPECT_NE(what.find("occluded_from_origin(): target 21 ("), std::string::npos) << what;
  }
  EXPECT_THROW(scene.intersect(origins, directions, std::nan("")), InputError);
  EXPECT_THROW(scene.intersect(origins, directions, 0.0, std::nan("")), InputError);
  EXPECT_THROW(scene.occluded_from_origin(targets, std::nan("")), InputError);
  // Components up to 1.844e18 are traced; infinite t_max is the default.
  Eigen::MatrixX3d far = directions;
  far.row(3) << 1.8e18, 0.0, 1.0;  // runs beside the plate
  const std::vector<RayHit> hits = scene.intersect(origins, far, 0.0, inf);
  ASSERT_EQ(hits.size(), size_t(n));
  EXPECT_EQ(hits[3].triangle, -1);
  for (int i = 0; i < n; ++i) {
    if (i != 3) {
      EXPECT_NEAR(hits[i].t, 2.0f, 1e-5f) << i;
    }
  }
  const std::vector<std::uint8_t> occluded = scene.occluded_from_origin(targets, 0.999);
  EXPECT_EQ(std::count(occluded.begin(), occluded.end(), 1), n);
}

}  // namespace
}  // namespace pbve
