#include "pbve/edit/synth.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <numbers>
#include <random>
#include <sstream>

#include <tbb/parallel_for.h>
#include <Eigen/Geometry>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/visibility/ray_scene.hpp"

namespace pbve {

namespace fs = std::filesystem;
using std::numbers::pi;

namespace {

Mesh finish(Vertices v, Triangles f) {
  Mesh m;
  m.vertices = std::move(v);
  m.triangles = std::move(f);
  m.triangle_part.assign(static_cast<size_t>(m.num_triangles()), 0);
  m.part_names = {"object"};
  m.interior.assign(static_cast<size_t>(m.num_triangles()), 0);
  // Orient outwards: positive signed volume.
  const double vol = enclosed_volume(m.vertices, m.triangles);
  if (vol < 0)
    for (int t = 0; t < m.num_triangles(); ++t) std::swap(m.triangles(t, 1), m.triangles(t, 2));
  return m;
}

cv::Vec3f hsv_to_bgr(double h, double s, double v) {
  h = h - std::floor(h);
  const double c = v * s, x = c * (1 - std::abs(std::fmod(h * 6.0, 2.0) - 1)), m = v - c;
  double r = 0, g = 0, b = 0;
  switch (static_cast<int>(h * 6.0) % 6) {
    case 0:
      r = c, g = x;
      break;
    case 1:
      r = x, g = c;
      break;
    case 2:
      g = c, b = x;
      break;
    case 3:
      g = x, b = c;
      break;
    case 4:
      r = x, b = c;
      break;
    default:
      r = c, b = x;
      break;
  }
  return {static_cast<float>(255 * (b + m)), static_cast<float>(255 * (g + m)),
          static_cast<float>(255 * (r + m))};
}

}  // namespace

Mesh make_box_mesh(double w, double h, double t) {
  Vertices v(8, 3);
  for (int i = 0; i < 8; ++i)
    v.row(i) << ((i & 1) ? w / 2 : -w / 2), ((i & 2) ? h : 0.0), ((i & 4) ? t / 2 : -t / 2);
  Triangles f(12, 3);
  // Quads (outward for a right-handed frame), split in two.
  const int quads[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (int q = 0; q < 6; ++q) {
    f.row(2 * q) << quads[q][0], quads[q][1], quads[q][2];
    f.row(2 * q + 1) << quads[q][0], quads[q][2], quads[q][3];
  }
  return finish(std::move(v), std::move(f));
}

Mesh make_icosphere(double radius, int subdivisions) {
  const double g = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, g, 0}, {1, g, 0}, {-1, -g, 0}, {1, -g, 0},
                                    {0, -1, g}, {0, 1, g}, {0, -1, -g}, {0, 1, -g},
                                    {g, 0, -1}, {g, 0, 1}, {-g, 0, -1}, {-g, 0, 1}};
  std::vector<std::array<int, 3>> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                       {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                       {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                       {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& p : v) p.normalize();
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      return mid[key] = static_cast<int>(v.size()) - 1;
    };
    std::vector<std::array<int, 3>> next;
    for (const auto& t : f) {
      const int ab = midpoint(t[0], t[1]), bc = midpoint(t[1], t[2]), ca = midpoint(t[2], t[0]);
      next.push_back({t[0], ab, ca});
      next.push_back({t[1], bc, ab});
      next.push_back({t[2], ca, bc});
      next.push_back({ab, bc, ca});
    }
    f = std::move(next);
  }
  Vertices V(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) V.row(static_cast<Eigen::Index>(i)) = radius * v[i];
  Triangles F(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i)
    F.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  return finish(std::move(V), std::move(F));
}

Mesh make_figurine(double height, int rings, int segments) {
  // Fewer rings leave no ring of vertices between the poles (the triangles then index vertices
  // that do not exist); fewer segments make rings of one or two vertices (flat triangles) or none.
  if (rings < 2)
    throw InputError("make_figurine: rings must be at least 2, got " + std::to_string(rings));
  if (segments < 3)
    throw InputError("make_figurine: segments must be at least 3, got " + std::to_string(segments));
  if (!(height > 0.0) || !std::isfinite(height))
    throw InputError("make_figurine: height must be positive and finite, got " +
                     std::to_string(height));
  // 2 (rings - 1) segments triangles, indexed by int (checked before any allocation).
  if (2 * (static_cast<long long>(rings) - 1) * segments + 2 > std::numeric_limits<int>::max())
    throw InputError("make_figurine: rings " + std::to_string(rings) + " x segments " +
                     std::to_string(segments) +
                     " make more vertices and triangles than int indices hold");
  // Profile radius over t in [0, 1] (feet at t = 0, top of the head at t = 1).
  auto radius = [&](double t) {
    const double body = 0.24 * std::sqrt(std::max(0.0, 1.0 - std::pow((t - 0.33) / 0.36, 2)));
    const double head = 0.16 * std::sqrt(std::max(0.0, 1.0 - std::pow((t - 0.83) / 0.17, 2)));
    const double neck = 0.07 * std::exp(-std::pow((t - 0.68) / 0.05, 2));
    return height * std::max({body, head, neck, 0.0});
  };
  std::vector<Eigen::Vector3d> v;
  v.push_back({0, 0, 0});  // bottom pole
  for (int i = 1; i < rings; ++i) {
    const double t = static_cast<double>(i) / rings;
    // Keep the feet a flat-ish disc: a minimum radius near the bottom.
    const double r = std::max(radius(t), t < 0.05 ? height * 0.12 * std::sqrt(t / 0.05) : 0.0);
    for (int j = 0; j < segments; ++j) {
      const double a = 2 * pi * j / segments;
      double x = r * std::cos(a), z = r * std::sin(a);
      // Belly bulge towards -z (the camera side), strongest at t = 0.33.
      if (z < 0) z *= 1.0 + 0.35 * std::exp(-std::pow((t - 0.33) / 0.15, 2));
      v.push_back({x, -height * t, z});
    }
  }
  v.push_back({0, -height, 0});  // top pole
  std::vector<std::array<int, 3>> f;
  auto ring = [&](int i, int j) { return 1 + (i - 1) * segments + (j % segments); };
  for (int j = 0; j < segments; ++j) f.push_back({0, ring(1, j + 1), ring(1, j)});
  for (int i = 1; i < rings - 1; ++i)
    for (int j = 0; j < segments; ++j) {
      f.push_back({ring(i, j), ring(i, j + 1), ring(i + 1, j + 1)});
      f.push_back({ring(i, j), ring(i + 1, j + 1), ring(i + 1, j)});
    }
  const int top = static_cast<int>(v.size()) - 1;
  for (int j = 0; j < segments; ++j) f.push_back({top, ring(rings - 1, j), ring(rings - 1, j + 1)});
  Vertices V(static_cast<Eigen::Index>(v.size()), 3);
  for (size_t i = 0; i < v.size(); ++i) V.row(static_cast<Eigen::Index>(i)) = v[i];
  Triangles F(static_cast<Eigen::Index>(f.size()), 3);
  for (size_t i = 0; i < f.size(); ++i)
    F.row(static_cast<Eigen::Index>(i)) << f[i][0], f[i][1], f[i][2];
  return finish(std::move(V), std::move(F));
}

SurfaceTexture procedural_texture(double period) {
  return [period](const Eigen::Vector3d& p, const Eigen::Vector3d& n) -> cv::Vec3f {
    const double u = p.x() / period, w = p.y() / period, d = p.z() / period;
    const double stripes = 0.5 + 0.5 * std::sin(2 * pi * (u + 0.5 * w));
    const double dots =
        std::pow(std::sin(pi * 3 * u) * std::sin(pi * 3 * (w + d)), 2) > 0.6 ? 1.0 : 0.0;
    double hue = 0.08 * u + 0.11 * w + 0.13 * d;
    // A distinct base hue per dominant normal direction: each side looks different.
    const Eigen::Vector3d a = n.cwiseAbs();
    if (a.z() >= a.x() && a.z() >= a.y())
      hue += n.z() < 0 ? 0.0 : 0.5;
    else if (a.x() >= a.y())
      hue += n.x() < 0 ? 0.17 : 0.67;
    else
      hue += n.y() < 0 ? 0.33 : 0.83;
    const double sat = 0.55 + 0.35 * stripes;
    const double val = 0.55 + 0.3 * (1 - dots) + 0.15 * stripes;
    return hsv_to_bgr(hue, sat, std::min(1.0, val));
  };
}

cv::Mat make_background(cv::Size size, unsigned seed) {
  if (size.width < 1 || size.height < 1)
    throw InputError("make_background: the size must be positive, got " +
                     std::to_string(size.width) + "x" + std::to_string(size.height));
  cv::Mat img(size, CV_8UC3);
  for (int y = 0; y < size.height; ++y)
    for (int x = 0; x < size.width; ++x) {
      const double fx = static_cast<double>(x) / size.width,
                   fy = static_cast<double>(y) / size.height;
      img.at<cv::Vec3b>(y, x) =
          cv::Vec3b(static_cast<uchar>(90 + 60 * fx), static_cast<uchar>(120 + 50 * fy),
                    static_cast<uchar>(140 + 40 * (1 - fx) * fy));
    }
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> px(0, size.width - 1), py(0, size.height - 1), col(30, 230),
      rad(8, std::max(9, size.width / 12));
  for (int i = 0; i < 40; ++i) {
    const cv::Scalar c(col(rng), col(rng), col(rng));
    if (i % 3 == 0)
      cv::circle(img, {px(rng), py(rng)}, rad(rng), c, cv::FILLED, cv::LINE_AA);
    else if (i % 3 == 1)
      cv::rectangle(img, cv::Rect(px(rng), py(rng), rad(rng) * 2, rad(rng)), c, cv::FILLED,
                    cv::LINE_AA);
    else
      cv::line(img, {px(rng), py(rng)}, {px(rng), py(rng)}, c, 3, cv::LINE_AA);
  }
  for (int i = 0; i < 12; ++i)
    cv::putText(img, "pbve", {px(rng), py(rng)}, cv::FONT_HERSHEY_SIMPLEX, 0.6 + (i % 3) * 0.3,
                cv::Scalar(col(rng), col(rng), col(rng)), 2, cv::LINE_AA);
  return img;
}

cv::Mat render_object(const Mesh& mesh, const Pose& pose, const Camera& camera,
                      const SurfaceTexture& texture, const cv::Mat& background, int supersample) {
  if (background.type() != CV_8UC3 || background.cols != camera.width ||
      background.rows != camera.height)
    throw InputError("render_object: the background must be 8-bit BGR of the camera's size " +
                     std::to_string(camera.width) + "x" + std::to_string(camera.height) + ", got " +
                     std::to_string(background.cols) + "x" + std::to_string(background.rows) +
                     " with " + std::to_string(background.channels()) + " channels");
  if (supersample < 1)
    throw InputError("render_object: supersample must be at least 1, got " +
                     std::to_string(supersample));
  if (!texture) throw InputError("render_object: no texture");
  const Vertices posed = pose.apply(mesh.vertices);
  RayScene scene(posed, mesh.triangles);
  const PrimaryHits hits = scene.cast_primary(camera, supersample);
  const Vertices normals = triangle_normals(mesh.vertices, mesh.triangles);
  cv::Mat out(camera.height, camera.width, CV_8UC3);
  const int ss = supersample;
  tbb::parallel_for(0, camera.height, [&](int y) {
    for (int x = 0; x < camera.width; ++x) {
      cv::Vec3f acc(0, 0, 0);
      const cv::Vec3b bg = background.at<cv::Vec3b>(y, x);
      for (int sy = 0; sy < ss; ++sy)
        for (int sx = 0; sx < ss; ++sx) {
          const int X = x * ss + sx, Y = y * ss + sy;
          const size_t k = static_cast<size_t>(Y) * hits.width + X;
          const int t = hits.triangle[k];
          if (t < 0) {
            acc += cv::Vec3f(bg[0], bg[1], bg[2]);
            continue;
          }
          const double u = hits.u[k], v = hits.v[k];
          const Eigen::Vector3d p =
              (1 - u - v) * mesh.vertices.row(mesh.triangles(t, 0)).transpose() +
              u * mesh.vertices.row(mesh.triangles(t, 1)).transpose() +
              v * mesh.vertices.row(mesh.triangles(t, 2)).transpose();
          const Eigen::Vector3d n = normals.row(t).normalized().transpose();
          const Eigen::Vector3d n_cam = pose.rotation * n;
          const Eigen::Vector3d ray = camera.ray_direction(hits.sample_position(X, Y));
          const double shade = 0.35 + 0.65 * std::abs(n_cam.dot(ray));
          acc += texture(p, n) * static_cast<float>(shade);
        }
      acc *= 1.0f / static_cast<float>(ss * ss);
      out.at<cv::Vec3b>(y, x) =
          cv::Vec3b(cv::saturate_cast<uchar>(acc[0]), cv::saturate_cast<uchar>(acc[1]),
                    cv::saturate_cast<uchar>(acc[2]));
    }
  });
  return out;
}

SynthRecipe synth_recipe(const SynthOptions& o) {
  if (o.frames < 1) throw InputError("frames must be at least 1", {}, 0, "--frames");
  if (o.width < 16 || o.height < 16) throw InputError("image size too small", {}, 0, "--size");
  if (o.width > 16384 || o.height > 16384)
    throw InputError("image size too large (at most 16384 pixels a side)", {}, 0, "--size");
  if (o.supersample < 1 || o.supersample > 8)
    throw InputError("supersample must be 1 to 8, got " + std::to_string(o.supersample), {}, 0,
                     "--supersample");
  if (!(o.fps > 0.0 && o.fps <= 1e6))
    throw InputError("fps must be above 0 and at most 1e6, got " + std::to_string(o.fps), {}, 0,
                     "--fps");
  SynthRecipe r;
  r.camera.width = o.width;
  r.camera.height = o.height;
  r.camera.fx = r.camera.fy = 600.0 * o.width / 640.0;
  r.camera.cx = (o.width - 1) / 2.0;
  r.camera.cy = (o.height - 1) / 2.0;
  const int n = o.single_image ? 1 : o.frames;
  const double dt = 1.0 / o.fps;
  auto ramp = [](double t) {
    return t < 0.5 ? 0.5 - 0.5 * std::cos(2 * pi * t) : 1.0;
  };  // 0 -> 1 over 0.5 s
  std::ostringstream scene;
  std::string engine = "mass_spring", material, anchors, extra_sim, extra_obj, extra_control;
  std::string substeps = "3", margin = "0.01", max_iterations = "20";
  Eigen::Vector3d base;
  Eigen::Matrix3d tilt = Eigen::Matrix3d::Identity();  // the object's rest orientation
  if (o.shape == "board") {
    r.mesh = make_box_mesh(0.40, 0.30, 0.01);
    base = {0.0, -0.13, 1.3};
    material = "cloth";
    // The hand holds the middle 10 cm of the top edge.
    anchors = "{box: {min: [-0.05, -0.001, -1], max: [0.05, 0.001, 1]}}";
    extra_obj = "  refine: 0.05\n";
  } else if (o.shape == "figurine") {
    r.mesh = make_figurine(0.36, 32, 32);
    base = {0.0, 0.18, 1.3};
    material = "elastic";
    anchors = "{box: {min: [-1, -0.03, -1], max: [1, 0.001, 1]}}";
    // A jelly belly: the band from 4 to 24 cm above the feet is soft (1.4e5 Pa), the feet and
    // the head firmer (4e5 Pa). The elastic preset (2e4 Pa) cannot carry a 36 cm figurine's
    // own weight. This belly stands still and nods at single pushes, but the rhythm of `push`
    // folds it over without control (the failure the controls prevent; docs/examples.md).
    extra_sim =
        "  volume_stiffness: 400000\n"
        "  regions: [{box: {min: [-1, -0.24, -1], max: [1, -0.04, 1]}, volume_stiffness: "
        "140000}]\n";
  } else if (o.shape == "ball") {
    r.mesh = make_icosphere(0.08, 3);
    base = {0.0, 0.0, 1.3};
    material = "elastic";
    anchors = "{vertices: []}";
    extra_sim = "  ground: {point: [0, 0.17, 0], normal: [0, -1, 0], friction: 0.5}\n";
  } else if (o.shape == "statue") {
    // A stone block caught falling: 12 cm above the ground, leaning and turned, so its pieces
    // land, tumble and scatter (the paper's shattering statue, a Bullet rigid-body scene).
    r.mesh = make_box_mesh(0.14, 0.30, 0.10);
    base = {0.0, -0.14, 1.2};
    tilt = (Eigen::AngleAxisd(25.0 * pi / 180.0, Eigen::Vector3d::UnitY()) *
            Eigen::AngleAxisd(12.0 * pi / 180.0, Eigen::Vector3d::UnitZ()))
               .toRotationMatrix();
    engine = "bullet";
    material = "rigid";
    substeps = "10";
    anchors = "{vertices: []}";
    extra_obj = "  fracture: {pieces: 8, seed: 1}\n";
    extra_sim = "  ground: {point: [0, 0.30, 0], normal: [0, -1, 0], friction: 0.6}\n";
    // Central differences through colliding pieces are rough: unbounded, a line search can
    // fling a piece away. Each component stays within twice the piece's weight.
    extra_control = "  force_bound: 2\n";
  } else {
    throw InputError("unknown shape '" + o.shape + "' (board, figurine, ball or statue)", {}, 0,
                     "--shape");
  }
  if (!o.engine.empty() && o.engine != engine) {
    if (o.engine != "mass_spring" && o.engine != "bullet")
      throw InputError("unknown engine '" + o.engine + "' (mass_spring or bullet)", {}, 0,
                       "--engine");
    if (material == "rigid")
      throw InputError("the " + o.shape + " is rigid pieces: it needs engine bullet", {}, 0,
                       "--engine");
    engine = o.engine;
    if (engine == "bullet") {
      // Central differences through Bullet: one acceleration per cluster of at-risk vertices.
      extra_control += "  clusters: 16\n";
      // Bullet has one material per object and no interior lattice: its elastic preset (a
      // volume-preserving pressure of 2e4 Pa; 2e5 Pa made the figurine diverge in frame 4).
      if (o.shape == "figurine") extra_sim.clear();
      if (o.shape == "board") {
        // A light cloth that follows the swing: ten substeps of ten solver passes keep Bullet's
        // position-based links nearly inextensible, full bending links, and velocity damping of
        // 1.5% per substep (a time constant of 0.22 s, a light cloth in air). The barrier starts
        // 3 degrees short of edge-on; six evaluations per frame.
        substeps = "10";
        extra_sim += "  position_iterations: 10\n  bending_stiffness: 1\n  damping: 0.015\n";
        margin = "0.05";
        max_iterations = "6";
      }
    }
  }
  for (int i = 0; i < n; ++i) {
    const double t = i * dt;
    Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
    Eigen::Vector3d p = base;
    if (o.motion == "swing") {
      // Yaw (up to 80 degrees, nearly edge-on) about the vertical axis through the middle of
      // the held edge, and a sideways sway.
      const double amplitude = o.amplitude_deg > 0.0 ? o.amplitude_deg : 80.0;
      const double frequency = o.frequency_hz > 0.0 ? o.frequency_hz : 0.9;
      const double yaw = (amplitude * pi / 180.0) * ramp(t) * std::sin(2 * pi * frequency * t);
      R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
      p.x() += 0.10 * ramp(t) * std::sin(2 * pi * 0.3 * t);
    } else if (o.motion == "wave") {
      const double roll = (25.0 * pi / 180.0) * ramp(t) * std::sin(2 * pi * 0.8 * t);
      const double yaw = (30.0 * pi / 180.0) * ramp(t) * std::sin(2 * pi * 0.4 * t);
      R = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()) *
           Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitZ()))
              .toRotationMatrix();
    } else if (o.motion == "stop") {
      // Moved sideways with a turn, then stopped abruptly at mid-clip.
      const double T = 0.5 * n * dt;
      const double s = std::min(t, T) / T;
      const double e = s * s * (3 - 2 * s);
      p.x() += -0.15 + 0.30 * (t < T ? s : 1.0) * (1.0 - 0.0 * e);
      const double amplitude = o.amplitude_deg > 0.0 ? o.amplitude_deg : 20.0;
      const double yaw = (amplitude * pi / 180.0) * (t < T ? std::sin(pi * s) : 0.0);
      R = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()).toRotationMatrix();
    } else if (o.motion == "push") {
      // Every 0.96 s: pushed 18 cm towards the camera, speeding up for 0.48 s (to 0.75 m/s),
      // stopped abruptly, held 0.16 s and brought back smoothly in 0.32 s. What is soft pitches
      // over the held part at every stop; each push comes before the last nod has died out, so
      // the nods grow.
      const double distance = 0.18, push = 0.48, hold = 0.16, back = 0.32;
      const double c = std::fmod(t, push + hold + back);
      double z = 1.0;
      if (c < push) {
        z = (c / push) * (c / push);
      } else if (c > push + hold) {
        const double b = (c - push - hold) / back;
        z = 1.0 - b * b * (3.0 - 2.0 * b);
      }
      p.z() -= distance * z;
    } else if (o.motion == "bounce") {
      // A ball rolling to the right and bouncing on the ground line (rigid motion).
      const double g = 9.81, v0 = 1.6, period = 2 * v0 / g;
      const double tb = std::fmod(t, period);
      p.y() += -0.25 + (0.17 + 0.25 - 0.08) - (v0 * tb - 0.5 * g * tb * tb);
      p.x() += -0.25 + 0.25 * t;
      R = Eigen::AngleAxisd(0.25 * t / 0.08, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    } else if (o.motion == "orbit") {
      // Moved around the frame while turning about two axes (a handheld object shown around).
      const double s = ramp(t);
      p.x() += 0.08 * s * std::sin(2 * pi * 0.25 * t);
      p.y() += 0.04 * s * std::sin(2 * pi * 0.4 * t);
      p.z() += 0.10 * s * std::sin(2 * pi * 0.15 * t);
      const double yaw = (40.0 * pi / 180.0) * s * std::sin(2 * pi * 0.3 * t);
      const double pitch = (15.0 * pi / 180.0) * s * std::sin(2 * pi * 0.45 * t);
      R = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitY()) *
           Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitX()))
              .toRotationMatrix();
    } else if (o.motion != "still") {
      throw InputError(
          "unknown motion '" + o.motion + "' (swing, wave, stop, push, bounce, orbit or still)", {},
          0, "--motion");
    }
    Pose pose;
    pose.rotation = R * tilt;
    pose.translation = p;
    r.track.poses.push_back(pose);
  }
  scene << "# Synthetic clip made by `pbve synth --shape " << o.shape << " --motion " << o.motion
        << (o.engine.empty() ? "" : " --engine " + o.engine) << "`.\n";
  if (o.single_image)
    scene << "input: {image: " << o.video_name << ", frames: " << o.frames << ", fps: " << o.fps
          << "}\n";
  else
    scene << "input: {video: " << o.video_name << "}\n";
  scene << "camera: {fx: " << r.camera.fx << ", fy: " << r.camera.fy << ", cx: " << r.camera.cx
        << ", cy: " << r.camera.cy << "}\n";
  scene << "object:\n  mesh: object.obj\n  poses: poses.txt\n  scale: 1.01\n"
        << extra_obj << "  anchors: " << anchors << "\n";
  scene << "simulation:\n  engine: " << engine << "\n  material: " << material
        << "\n  gravity: [0, 9.81, 0]\n  substeps: " << substeps << "\n"
        << extra_sim;
  scene << "control:\n  enabled: true\n  weights: {visibility: 1.0, force: 0.03, temporal: 0.03}\n"
        << "  margin: " << margin
        << "\n  window: 1\n  solver: lbfgs\n  max_iterations: " << max_iterations
        << "\n  gradient: auto\n"
        << extra_control;
  scene << "output: {video: edited.mp4, report: report.json}\n";
  r.scene_yaml = scene.str();
  return r;
}

namespace {

// A hand (palm, four fingers, thumb and forearm, skin coloured) sweeping from right to left
// across the object's projection as `phase` goes from 0 to 1, over it between about 0.35 and
// 0.65 and covering up to about a third of it.
void draw_occluder(cv::Mat& img, const Mesh& mesh, const Pose& pose, const Camera& camera,
                   double phase) {
  double x0 = 1e9, x1 = -1e9, y0 = 1e9, y1 = -1e9;
  for (Eigen::Index i = 0; i < mesh.vertices.rows(); ++i) {
    const Eigen::Vector2d q = camera.project(pose.apply(Eigen::Vector3d(mesh.vertices.row(i))));
    x0 = std::min(x0, q.x());
    x1 = std::max(x1, q.x());
    y0 = std::min(y0, q.y());
    y1 = std::max(y1, q.y());
  }
  const double w = x1 - x0, h = y1 - y0;
  const double palm = 0.22 * std::max(w, h);
  const double cx = x1 + palm - (w + 2 * palm) * phase, cy = 0.5 * (y0 + y1) + 0.15 * h;
  const cv::Scalar skin(120, 160, 215), shade(100, 135, 190);
  auto pt = [](double x, double y) {
    return cv::Point(static_cast<int>(std::lround(x * 16)), static_cast<int>(std::lround(y * 16)));
  };
  const int s = static_cast<int>(std::lround(palm * 16));
  // Forearm towards the lower right corner, then palm, fingers and thumb.
  const std::vector<cv::Point> arm = {pt(cx, cy - 0.5 * palm), pt(cx + 3 * palm, cy + 2 * palm),
                                      pt(cx + 3 * palm, cy + 4 * palm), pt(cx, cy + 0.6 * palm)};
  cv::fillConvexPoly(img, arm, shade, cv::LINE_AA, 4);
  cv::ellipse(img, pt(cx, cy), cv::Size(s, static_cast<int>(s * 0.8)), 0, 0, 360, skin, cv::FILLED,
              cv::LINE_AA, 4);
  for (int f = 0; f < 4; ++f) {
    const double fx = cx - 0.7 * palm + f * 0.45 * palm, fy = cy - 1.25 * palm;
    cv::ellipse(img, pt(fx, fy), cv::Size(static_cast<int>(s * 0.2), static_cast<int>(s * 0.6)),
                -10 + 7 * f, 0, 360, skin, cv::FILLED, cv::LINE_AA, 4);
  }
  cv::ellipse(img, pt(cx - 1.1 * palm, cy + 0.1 * palm),
              cv::Size(static_cast<int>(s * 0.55), static_cast<int>(s * 0.22)), 30, 0, 360, skin,
              cv::FILLED, cv::LINE_AA, 4);
}

}  // namespace

// The files of a clip made from `r` (synthesize()).
static SynthOutput write_synth(const SynthOptions& o, const SynthRecipe& r,
                               const fs::path& out_dir);

SynthOutput synthesize(const SynthOptions& o, const fs::path& out_dir) {
  const SynthRecipe r = synth_recipe(o);  // checks the options before any file is written
  std::error_code ec;
  const bool created = !fs::exists(out_dir, ec);
  fs::create_directories(out_dir, ec);
  if (ec) throw InputError("cannot create the output folder: " + ec.message(), out_dir);
  try {
    return write_synth(o, r, out_dir);
  } catch (...) {
    if (created) fs::remove_all(out_dir, ec);  // a folder made for this run: all of it ours
    throw;
  }
}

static SynthOutput write_synth(const SynthOptions& o, const SynthRecipe& r,
                               const fs::path& out_dir) {
  SynthOutput out;
  out.camera = r.camera;
  out.track = r.track;
  out.mesh_data = r.mesh;
  out.mesh = out_dir / "object.obj";
  out.poses = out_dir / "poses.txt";
  out.scene = out_dir / "scene.yaml";
  out.plate = out_dir / "plate_true.png";
  out.video = out_dir / o.video_name;
  cv::Mat background;
  const cv::Size size(o.width, o.height);
  if (!o.background.empty()) {
    background = cv::imread(o.background.string(), cv::IMREAD_COLOR);
    if (background.empty()) throw InputError("cannot read the background image", o.background);
    cv::resize(background, background, size, 0, 0, cv::INTER_AREA);
  } else {
    background = make_background(size, 7);
  }
  const SurfaceTexture texture = procedural_texture(0.06);
  save_obj(r.mesh, out.mesh);
  save_pose_file(r.track, out.poses);
  write_atomically(out.plate, [&](const fs::path& tmp) {
    if (!cv::imwrite(tmp.string(), background)) throw InputError("cannot write", out.plate);
  });
  if (o.single_image) {
    const cv::Mat img =
        render_object(r.mesh, *r.track.poses[0], r.camera, texture, background, o.supersample);
    write_atomically(out.video, [&](const fs::path& tmp) {
      if (!cv::imwrite(tmp.string(), img)) throw InputError("cannot write", out.video);
    });
  } else {
    VideoWriter writer(out.video, o.fps, size);
    const int n = r.track.size();
    for (int i = 0; i < n; ++i) {
      const Pose& pose = *r.track.poses[static_cast<size_t>(i)];
      cv::Mat img = render_object(r.mesh, pose, r.camera, texture, background, o.supersample);
      if (o.occluder) draw_occluder(img, r.mesh, pose, r.camera, n > 1 ? i / (n - 1.0) : 0.5);
      writer.write(img);
    }
    writer.close();
  }
  write_atomically(out.scene, [&](const fs::path& tmp) {
    std::ofstream f(tmp);
    f << r.scene_yaml;
    if (!f) throw InputError("cannot write", out.scene);
  });
  return out;
}

}  // namespace pbve
