// Renderer: the identity invariant, antialiased edges, the fail-safe, interior colour,
// removal and extra masks, and input checks.

#include "pbve/render/renderer.hpp"

#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "pbve/core/error.hpp"
#include "pbve/visibility/visibility.hpp"
#include "render/render_scenes.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

using test::SyntheticFrame;

Camera test_camera() {
  return test::centred_camera(320, 240, 300.0);
}

Eigen::Matrix3d rotation(double angle, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(angle, axis.normalized()).toRotationMatrix();
}

/// A smooth colour of the mesh point, values in [48, 208].
cv::Vec3f smooth_color(const Eigen::Vector3d& p) {
  return {static_cast<float>(128 + 80 * std::sin(8 * p.x() + 2 * p.y())),
          static_cast<float>(128 + 80 * std::cos(7 * p.y() - 3 * p.z())),
          static_cast<float>(128 + 80 * std::sin(6 * p.z() + 4 * p.x()))};
}

cv::Mat to_mask(const cv::Mat& m) {
  return m != 0;
}

// When the simulated mesh is the aligned mesh, the output is the input: within 2/255 (mean
// absolute error) on the object's pixels and bit-exact away from it.
//
// Why this holds: an output pixel whose centre ray hits triangle j at barycentrics b is not an
// edge pixel, so its colour is one texture lookup at the projection of the same point of the
// same triangle on the aligned mesh, i.e. at the pixel centre itself (up to single-precision
// round-off, ~1e-4 px), where bilinear sampling returns the input pixel. Away from the object
// the output is the input, or the plate (here the true background, equal to the input there).
TEST(Renderer, IdentityReproducesTheInput) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(4, 0.3);  // 5120 triangles, ~55 px radius
  const cv::Mat background = test::smooth_background({camera.width, camera.height});
  Renderer renderer(sphere, camera);
  const std::vector<std::pair<Eigen::Matrix3d, Eigen::Vector3d>> poses = {
      {rotation(0.3, {1, 2, 0}), {0.0, 0.0, 1.6}},
      {rotation(1.2, {0, 1, 1}), {-0.25, 0.1, 1.7}},
      {rotation(2.5, {1, 0, 1}), {0.3, -0.15, 1.5}}};
  for (const auto& [R, t] : poses) {
    const Vertices cam_v = test::transform(sphere.vertices, R, t);
    const SyntheticFrame input = test::render_object(sphere.triangles, sphere.vertices, cam_v,
                                                     camera, background, smooth_color);
    const cv::Mat output = renderer.render(input.image, cam_v, cam_v, background);

    cv::Mat object, touched, away;
    cv::erode(to_mask(input.coverage == 1.0f), object, cv::Mat());  // edges excluded by 1 px
    cv::dilate(to_mask(input.coverage > 0.0f), touched, cv::Mat());
    away = touched == 0;
    ASSERT_GT(cv::countNonZero(object), 5000);
    const double mae = test::mean_abs_diff(output, input.image, object);
    RecordProperty("mae_object_levels", std::to_string(mae));
    EXPECT_LE(mae, 2.0);
    EXPECT_EQ(test::mean_abs_diff(output, input.image, away), 0.0)
        << "not bit-exact off the object";
    // The one-pixel band in between is antialiased on both sides (4x4 samples in the input, 3x3
    // in the renderer); its error stays a fraction of the object/background contrast.
    cv::Mat band = touched & ~object;
    EXPECT_LE(test::mean_abs_diff(output, input.image, band), 8.0);
    EXPECT_EQ(renderer.stats().unobserved_triangles > 0, true);  // the far side of the sphere
    // Taps are only rejected for sub-samples of edge pixels that lie on the object while the
    // centres of the input pixels around them do not: at most a few per edge pixel.
    EXPECT_LT(renderer.stats().rejected_samples, renderer.stats().edge_pixels);
  }
}

// Every supersampling level keeps the identity invariant; with one sample per pixel the matte is
// binary, with s x s samples it takes multiples of 1 / s^2.
TEST(Renderer, SupersampleLevels) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(3, 0.3);
  const cv::Mat background = test::smooth_background({camera.width, camera.height});
  const Vertices v = test::transform(sphere.vertices, rotation(0.4, {1, 1, 0}), {0.05, 0, 1.6});
  const SyntheticFrame input =
      test::render_object(sphere.triangles, sphere.vertices, v, camera, background, smooth_color);
  cv::Mat object, touched;
  cv::erode(to_mask(input.coverage == 1.0f), object, cv::Mat());
  cv::dilate(to_mask(input.coverage > 0.0f), touched, cv::Mat());
  for (const int s : {1, 2, 4}) {
    RenderOptions options;
    options.supersample = s;
    Renderer renderer(sphere, camera, options);
    const cv::Mat output = renderer.render(input.image, v, v, background);
    EXPECT_LE(test::mean_abs_diff(output, input.image, object), 2.0) << s;
    EXPECT_EQ(test::mean_abs_diff(output, input.image, touched == 0), 0.0) << s;
    int off_grid = 0;
    for (int y = 0; y < camera.height; ++y)
      for (int x = 0; x < camera.width; ++x) {
        const float m = renderer.matte().at<float>(y, x) * s * s;
        off_grid += std::abs(m - std::round(m)) > 1e-4f;
      }
    EXPECT_EQ(off_grid, 0) << s;
    if (s == 1) {
      EXPECT_EQ(renderer.stats().edge_pixels, 0);
    } else {
      EXPECT_GT(renderer.stats().edge_pixels, 100);
    }
  }
}

// Edges are antialiased: the matte is fractional along the silhouette and close to the true
// coverage, and composited edge pixels lie between object and background colour (no dark
// fringe) even where the simulated silhouette is not where the original one was.
TEST(Renderer, AntialiasedEdgesWithoutFringe) {
  const Camera camera = test_camera();
  const Mesh cube = test::box(0.2, 4);
  const cv::Vec3f object_color(40, 200, 90);
  const cv::Mat background(camera.height, camera.width, CV_8UC3, cv::Scalar(230, 60, 20));
  const Eigen::Matrix3d R = rotation(0.6, {1, 1, 0});
  const Vertices aligned = test::transform(cube.vertices, R, {0.0, 0.0, 1.5});
  const Vertices simulated =
      test::transform(cube.vertices, rotation(0.5, {0, 0, 1}) * R, {0.07, 0.03, 1.45});
  const auto uniform = [&](const Eigen::Vector3d&) { return object_color; };
  const SyntheticFrame input =
      test::render_object(cube.triangles, cube.vertices, aligned, camera, background, uniform);
  // Reference coverage of the simulated cube with 12 x 12 samples per pixel.
  const SyntheticFrame reference = test::render_object(cube.triangles, cube.vertices, simulated,
                                                       camera, background, uniform, 12);
  Renderer renderer(cube, camera);
  const cv::Mat output = renderer.render(input.image, aligned, simulated, background);

  const cv::Mat& matte = renderer.matte();
  const cv::Mat edge = to_mask(reference.coverage > 0.0f) & to_mask(reference.coverage < 1.0f);
  ASSERT_GT(cv::countNonZero(edge), 200);
  const cv::Mat fractional = to_mask(matte > 0.0f) & to_mask(matte < 1.0f);
  EXPECT_GT(cv::countNonZero(fractional), cv::countNonZero(edge) / 2);
  // 3 x 3 point samples estimate a pixel's coverage to within about one sample (1/9) on
  // average along a straight edge; the mean error must stay below that.
  cv::Mat diff;
  cv::absdiff(matte, reference.coverage, diff);
  EXPECT_LT(cv::mean(diff, edge)[0], 1.0 / 9.0);
  // Every output pixel is a convex combination of the object colour and the background colour:
  // texture samples near the original silhouette are themselves such mixtures and the plate is
  // the background. Allow 1 level per channel for rounding.
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      const cv::Vec3b p = output.at<cv::Vec3b>(y, x);
      const cv::Vec3b b = background.at<cv::Vec3b>(y, x);
      for (int c = 0; c < 3; ++c) {
        ASSERT_GE(p[c] + 1, std::min<float>(object_color[c], b[c])) << x << "," << y;
        ASSERT_LE(p[c] - 1, std::max<float>(object_color[c], b[c])) << x << "," << y;
      }
    }
}

// With the fail-safe on, no colour comes from outside the object in the input frame. The input
// background is pure magenta, the object's colours are green-dominant (G >= 150, R, B <= 120),
// and a magenta "hand" (given as the extra mask) lies across the ring in the input. The
// simulated torus is turned around so that its back faces (unobserved: filled from the
// observed surface) and the parts hidden by the hand face the camera.
TEST(Renderer, FailSafeNeverSamplesOutsideTheObject) {
  const Camera camera = test_camera();
  const Mesh ring = test::torus(0.3, 0.1, 64, 32);
  const cv::Mat magenta(camera.height, camera.width, CV_8UC3, cv::Scalar(255, 0, 255));
  const cv::Mat grey(camera.height, camera.width, CV_8UC3, cv::Scalar(128, 128, 128));
  const auto green = [](const Eigen::Vector3d& p) {
    return cv::Vec3f(static_cast<float>(80 + 40 * std::sin(10 * p.x())),
                     static_cast<float>(190 + 40 * std::sin(9 * p.y() + 3 * p.z())),
                     static_cast<float>(80 + 40 * std::cos(11 * p.z() + 2 * p.x())));
  };
  const Eigen::Matrix3d R = rotation(1.0, {1, 0, 0});
  const Eigen::Vector3d t(0.0, 0.0, 1.8);
  const Vertices aligned = test::transform(ring.vertices, R, t);
  const Vertices simulated = test::transform(ring.vertices, rotation(2.6, {0.2, 1, 0}) * R,
                                             t + Eigen::Vector3d(0.05, 0, 0));
  test::SyntheticFrame input =
      test::render_object(ring.triangles, ring.vertices, aligned, camera, magenta, green);
  const cv::Rect hand(100, 90, 24, 80);
  cv::Mat hand_mask(camera.height, camera.width, CV_8U, cv::Scalar(0));
  hand_mask(hand).setTo(255);
  input.image(hand).setTo(cv::Scalar(255, 0, 255));
  // v_j from the mesh alone: triangles behind the hand still count as observed; only the mask
  // tells the renderer that those input pixels do not show the object.
  const std::vector<std::uint8_t> observed =
      compute_visibility(RayScene(aligned, ring.triangles), camera).visible;

  // A colour is "near magenta" when more than ~60% of it is magenta: a mix
  // (1 - a) obj + a magenta has G = (1 - a) G_obj <= (1 - a) 230 and R, B >= a 255. Texture
  // near the original silhouette comes from input pixels whose centre is on the object, i.e.
  // at most about half magenta (G >= 75), so the bound separates the two cases. Checked on the
  // object's own colour (before the matte blend) at every pixel the simulated object touches.
  const auto count_near_magenta = [&](const Renderer& r) {
    int n = 0;
    for (int y = 0; y < camera.height; ++y)
      for (int x = 0; x < camera.width; ++x) {
        if (r.matte().at<float>(y, x) <= 0.0f) continue;
        const cv::Vec3f p = r.foreground().at<cv::Vec3f>(y, x);
        n += (p[1] < 60 && p[0] > 150 && p[2] > 150);
      }
    return n;
  };

  Renderer safe(ring, camera);
  const cv::Mat output = safe.render(input.image, aligned, simulated, observed, grey, hand_mask);
  ASSERT_GT(safe.stats().unobserved_triangles, 0);
  EXPECT_GT(safe.stats().fallback_samples, 1000);  // the back faces are on screen
  EXPECT_GT(safe.stats().covered_pixels, 5000);
  EXPECT_GT(safe.stats().rejected_samples, 100);  // samples whose input pixels are the hand
  EXPECT_EQ(count_near_magenta(safe), 0);
  // No black holes either: every touched pixel has an object-like colour.
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x)
      if (safe.matte().at<float>(y, x) > 0.0f) {
        ASSERT_GT(safe.foreground().at<cv::Vec3f>(y, x)[1], 75.0f) << x << "," << y;
      }
  // Where the simulated object covers a pixel entirely, the output is its colour: no magenta.
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x)
      if (safe.matte().at<float>(y, x) == 1.0f) {
        ASSERT_GT(output.at<cv::Vec3b>(y, x)[1], 75) << x << "," << y;
      }

  // The same scene without the fail-safe does show magenta (texture taken from the hand): the
  // test can see the failure it guards against.
  RenderOptions unsafe_options;
  unsafe_options.fail_safe = false;
  Renderer unsafe(ring, camera, unsafe_options);
  unsafe.render(input.image, aligned, simulated, observed, grey, hand_mask);
  EXPECT_GT(count_near_magenta(unsafe), 100);
}

// Interior (fracture) triangles get one uniform colour: the configured one, or by default
// interior_shade times the object's mean colour in the input frame.
TEST(Renderer, InteriorTrianglesAreUniform) {
  const Camera camera = test_camera();
  Mesh cube = test::box(0.2, 4);
  const int per_face = 2 * 4 * 4;
  for (int j = 0; j < per_face; ++j) cube.interior[j] = 1;  // the +x face
  const cv::Mat background = test::smooth_background({camera.width, camera.height});
  // Input: +x face turned away from the camera; simulation: turned towards it.
  const Vertices aligned =
      test::transform(cube.vertices, rotation(-1.0, {0, 1, 0}), {0.0, 0.0, 1.4});
  const Vertices simulated =
      test::transform(cube.vertices, rotation(0.7, {0, 1, 0.2}), {0.0, 0.0, 1.4});
  const SyntheticFrame input =
      test::render_object(cube.triangles, cube.vertices, aligned, camera, background, smooth_color);
  // Pixels whose 3 x 3 sub-samples (the renderer's pattern) all hit interior triangles.
  const PrimaryHits hits = RayScene(simulated, cube.triangles).cast_primary(camera, 3);
  cv::Mat inside(camera.height, camera.width, CV_8U, cv::Scalar(0));
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      bool all = true;
      for (int k = 0; k < 9 && all; ++k) {
        const int tri =
            hits.triangle[static_cast<size_t>(3 * y + k / 3) * hits.width + 3 * x + k % 3];
        all = tri >= 0 && cube.interior[tri];
      }
      inside.at<uchar>(y, x) = all ? 255 : 0;
    }
  ASSERT_GT(cv::countNonZero(inside), 1000);

  for (const bool configured : {false, true}) {
    RenderOptions options;
    if (configured) options.interior_color = cv::Vec3f(10, 200, 30);
    Renderer renderer(cube, camera, options);
    const cv::Mat output = renderer.render(input.image, aligned, simulated, background);
    const cv::Vec3f expected =
        configured ? cv::Vec3f(10, 200, 30) : renderer.stats().object_mean_color * 0.8f;
    EXPECT_LT(cv::norm(renderer.stats().interior_color - expected), 1e-3);
    const cv::Vec3b expected8(cv::saturate_cast<uchar>(expected[0]),
                              cv::saturate_cast<uchar>(expected[1]),
                              cv::saturate_cast<uchar>(expected[2]));
    int wrong = 0;
    for (int y = 0; y < camera.height; ++y)
      for (int x = 0; x < camera.width; ++x)
        if (inside.at<uchar>(y, x)) wrong += output.at<cv::Vec3b>(y, x) != expected8;
    EXPECT_EQ(wrong, 0) << (configured ? "configured" : "default") << " interior colour";
  }
}

// The original object (enlarged by `scale`, dilated) and the extra mask are replaced by the
// plate where the simulated object does not cover them.
TEST(Renderer, RemovedPixelsComeFromThePlate) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(3, 0.25);
  const cv::Mat background = test::smooth_background({camera.width, camera.height});
  const cv::Mat plate(camera.height, camera.width, CV_8UC3, cv::Scalar(17, 34, 51));
  const Vertices aligned =
      test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {-0.3, 0.0, 1.6});
  const Vertices simulated =
      test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {0.3, 0.0, 1.6});
  const SyntheticFrame input = test::render_object(sphere.triangles, sphere.vertices, aligned,
                                                   camera, background, smooth_color);
  cv::Mat extra(camera.height, camera.width, CV_8U, cv::Scalar(0));
  extra(cv::Rect(140, 10, 40, 30)).setTo(1);

  Renderer renderer(sphere, camera);
  const cv::Mat output = renderer.render(input.image, aligned, simulated, plate, extra);
  // The removal mask contains the exact enlarged, dilated silhouette and the extra mask, and
  // exceeds it by at most the rounding of the enlargement bound (the 1% enlargement moves this
  // ~47 px sphere's outline by ~0.5 px, the bound adds 0.75 px and rounds up: <= 2 px more).
  const cv::Mat silhouette = silhouette_mask(sphere.triangles, aligned, camera, 1.01, 2);
  const cv::Mat removed = renderer.removal_mask();
  EXPECT_EQ(cv::countNonZero((silhouette | (extra != 0)) & ~removed), 0);
  const cv::Mat loose = silhouette_mask(sphere.triangles, aligned, camera, 1.01, 4);
  EXPECT_EQ(cv::countNonZero(removed & ~(loose | (extra != 0))), 0);
  const cv::Mat& expected_removed = removed;
  // Every pixel the original object touched is removed (the 1% enlargement and the dilation
  // cover the partly covered edge pixels).
  EXPECT_EQ(cv::countNonZero(to_mask(input.coverage > 0.0f) & ~silhouette), 0);
  for (int y = 0; y < camera.height; ++y)
    for (int x = 0; x < camera.width; ++x) {
      if (renderer.matte().at<float>(y, x) > 0.0f) continue;
      const cv::Vec3b expected = expected_removed.at<uchar>(y, x) ? plate.at<cv::Vec3b>(y, x)
                                                                  : input.image.at<cv::Vec3b>(y, x);
      ASSERT_EQ(output.at<cv::Vec3b>(y, x), expected) << x << "," << y;
    }
}

TEST(Renderer, SilhouetteMaskScalesAboutTheCentroid) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(4, 0.3);
  const Vertices v = test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {0, 0, 2.0});
  const int base = cv::countNonZero(silhouette_mask(sphere.triangles, v, camera, 1.0, 0));
  const int big = cv::countNonZero(silhouette_mask(sphere.triangles, v, camera, 1.1, 0));
  // Radius ~45 px: area scales by about 1.1^2 (the perspective of a sphere changes this by
  // well under 1%); allow 3% for the pixel-centre discretization of the boundary.
  EXPECT_NEAR(static_cast<double>(big) / base, 1.21, 0.03);
  EXPECT_GT(cv::countNonZero(silhouette_mask(sphere.triangles, v, camera, 1.0, 3)), base);
  EXPECT_EQ(surface_centroid(v, sphere.triangles).isApprox(Eigen::Vector3d(0, 0, 2.0), 1e-9), true);
}

TEST(Renderer, RejectsMismatchedInput) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(2, 0.25);
  const Vertices v = test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {0, 0, 1.5});
  const cv::Mat frame(camera.height, camera.width, CV_8UC3, cv::Scalar(1, 2, 3));
  const std::vector<std::uint8_t> observed(static_cast<size_t>(sphere.num_triangles()), 1);
  Renderer renderer(sphere, camera);
  EXPECT_THROW(renderer.render(cv::Mat(10, 10, CV_8UC3), v, v, observed, frame), InputError);
  EXPECT_THROW(renderer.render(frame, v, v, observed, cv::Mat()), InputError);
  EXPECT_THROW(renderer.render(frame, v.topRows(3), v, observed, frame), InputError);
  EXPECT_THROW(renderer.render(frame, v, v, std::vector<std::uint8_t>(3, 1), frame), InputError);
  EXPECT_THROW(renderer.render(frame, v, v, observed, frame, cv::Mat(5, 5, CV_8U)), InputError);
  RenderOptions bad;
  bad.supersample = 0;
  EXPECT_THROW(Renderer(sphere, camera, bad), InputError);
  EXPECT_NO_THROW(renderer.render(frame, v, v, observed, frame));
}

// A focal length so short that the rays through the image's edges have direction components
// beyond Embree's range (1.844e18) is refused when the Renderer is made: render() aborted the
// process inside Embree.
TEST(Renderer, RefusesAFocalLengthTooShortForItsRays) {
  const Mesh sphere = test::icosphere(2, 0.25);
  for (const double f : {1e-40, 1e-20}) {  // components of 1.6e42 (inf in float) and 1.6e22
    Camera camera = test_camera();
    camera.fx = f;
    EXPECT_THROW(Renderer(sphere, camera), InputError) << f;
    camera = test_camera();
    camera.fy = f;
    EXPECT_THROW(Renderer(sphere, camera), InputError) << f;
  }
}

TEST(Renderer, SyntheticFootageRejectsMismatchedInput) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(2, 0.25);
  const Pose pose = Pose::from_rodrigues(Eigen::Vector3d::Zero(), {0, 0, 1.5});
  const SurfaceTexture texture = procedural_texture(0.1);
  const cv::Mat background = make_background({camera.width, camera.height});
  EXPECT_THROW(make_background({0, 0}), InputError);
  EXPECT_THROW(render_object(sphere, pose, camera, texture, cv::Mat(), 1), InputError);
  EXPECT_THROW(render_object(sphere, pose, camera, texture, background(cv::Rect(0, 0, 8, 8)), 1),
               InputError);
  EXPECT_THROW(render_object(sphere, pose, camera, texture, background, 0), InputError);
  EXPECT_THROW(render_object(sphere, pose, camera, SurfaceTexture(), background, 1), InputError);
  const cv::Mat image = render_object(sphere, pose, camera, texture, background, 1);
  EXPECT_EQ(image.size(), background.size());
  EXPECT_GT(cv::norm(image, background, cv::NORM_L1), 0.0);  // the sphere is drawn
}

// A mesh reaching behind the camera plane: projections are unbounded, so the removal mask falls
// back to casting the enlarged mesh, and the renderer neither fails nor samples garbage.
TEST(Renderer, MeshReachingBehindTheCamera) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(3, 0.3);
  const Vertices v = test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {0, 0, 0.2});
  const cv::Mat frame = test::smooth_background({camera.width, camera.height});
  const cv::Mat plate(camera.height, camera.width, CV_8UC3, cv::Scalar(9, 9, 9));
  Renderer renderer(sphere, camera);
  const cv::Mat output = renderer.render(frame, v, v, plate);
  const cv::Mat expected = silhouette_mask(sphere.triangles, v, camera, 1.01, 2);
  EXPECT_EQ(cv::countNonZero(renderer.removal_mask() != expected), 0);
  EXPECT_EQ(output.size(), frame.size());
  // The camera is inside the sphere: every pixel sees its inside (back faces, unobserved), so
  // everything is fail-safe colour, and with nothing observed that is the object's mean colour
  // of the input (all of it), not black.
  EXPECT_EQ(renderer.stats().covered_pixels,
            static_cast<std::int64_t>(camera.width) * camera.height);
  const cv::Scalar mean = cv::mean(output);
  const cv::Scalar input_mean = cv::mean(frame);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(mean[c], input_mean[c], 2.0);
}

// An object entirely behind the camera or outside the image leaves the frame unchanged.
TEST(Renderer, ObjectOutOfViewLeavesTheFrame) {
  const Camera camera = test_camera();
  const Mesh sphere = test::icosphere(2, 0.25);
  const Vertices away = test::transform(sphere.vertices, Eigen::Matrix3d::Identity(), {5, 0, 1.5});
  const cv::Mat frame = test::smooth_background({camera.width, camera.height});
  Renderer renderer(sphere, camera);
  const std::vector<std::uint8_t> observed(static_cast<size_t>(sphere.num_triangles()), 0);
  const cv::Mat output = renderer.render(frame, away, away, observed, frame);
  EXPECT_EQ(cv::norm(output, frame, cv::NORM_INF), 0.0);
  EXPECT_EQ(renderer.stats().covered_pixels, 0);
}

}  // namespace
}  // namespace pbve
