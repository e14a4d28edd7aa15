#include "pbve/render/renderer.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

#include "pbve/core/error.hpp"
#include "pbve/render/vertex_fill.hpp"

namespace pbve {
namespace {

/// A camera that sees only the pixel rectangle `r` of `camera`: pixel (x, y) of the crop is
/// pixel (x + r.x, y + r.y) of the full image.
Camera crop_camera(const Camera& camera, const cv::Rect& r) {
  Camera crop = camera;
  crop.cx -= r.x;
  crop.cy -= r.y;
  crop.width = r.width;
  crop.height = r.height;
  return crop;
}

/// Primary hits of `scene` through the pixel centres of rectangle `r` (empty hits when `r` is
/// empty).
void cast_rect(const RayScene& scene, const Camera& camera, const cv::Rect& r, PrimaryHits& hits) {
  if (r.area() <= 0) {
    hits = PrimaryHits{};
    return;
  }
  hits = scene.cast_primary(crop_camera(camera, r), 1);
}

void check_image(const cv::Mat& image, int type, const Camera& camera, const char* what) {
  if (image.empty() || image.type() != type || image.cols != camera.width ||
      image.rows != camera.height)
    throw InputError(std::string(what) + ": expected a " +
                     (type == CV_8UC3 ? "8-bit BGR" : "8-bit single-channel") + " image of " +
                     std::to_string(camera.width) + "x" + std::to_string(camera.height) + ", got " +
                     (image.empty()
                          ? std::string("an empty image")
                          : std::to_string(image.cols) + "x" + std::to_string(image.rows) +
                                " with " + std::to_string(image.channels()) +
                                " channel(s), depth " + std::to_string(image.depth())));
}

void check_vertices(const Vertices& v, int nv, const char* what) {
  if (v.rows() != nv)
    throw InputError(std::string(what) + ": expected " + std::to_string(nv) + " vertices, got " +
                     std::to_string(v.rows()));
}

/// Counters accumulated by the parallel loops.
struct Counters {
  std::atomic<std::int64_t> covered{0}, fallback{0}, rejected{0};
};

/// Colour of a surface sample of the simulated mesh (see the file comment of renderer.hpp).
struct Shader {
  const cv::Mat& frame;
  const Camera& camera;
  const Vertices& aligned;
  const Triangles& triangles;
  const std::uint8_t* observed;
  const std::uint8_t* interior;
  const PrimaryHits& guard;  // aligned mesh's first hits over guard_rect (pixel centres)
  cv::Rect guard_rect;
  const cv::Vec3f* vertex_colors;
  const cv::Mat* extra_mask;  // CV_8U or null: input pixels not showing the object (the hand)
  cv::Vec3f interior_color;
  bool fail_safe;
  double depth_tolerance;

  /// Point of triangle `tri` of the aligned mesh at barycentrics (u, v), camera frame.
  Eigen::Vector3d aligned_point(int tri, double u, double v) const {
    const auto t = triangles.row(tri);
    return (1.0 - u - v) * aligned.row(t(0)).transpose() + u * aligned.row(t(1)).transpose() +
           v * aligned.row(t(2)).transpose();
  }

  /// Bilinear sample of the input frame at the projection of `p` (a point of triangle `tri`
  /// on the aligned mesh). With the fail-safe on, taps whose pixel centre does not show that
  /// surface (another triangle at a different depth, the background, or a pixel of the extra
  /// mask such as a hand in front of the object) are dropped and the remaining weights
  /// renormalized. Returns false when no tap is usable.
  bool sample(int tri, const Eigen::Vector3d& p, cv::Vec3f& out) const {
    if (!(p.z() > 0.0)) return false;
    const double x = camera.fx * p.x() / p.z() + camera.cx;
    const double y = camera.fy * p.y() / p.z() + camera.cy;
    if (!(x > -1.0 && x < frame.cols && y > -1.0 && y < frame.rows)) return false;
    const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
    const float ax = static_cast<float>(x - x0), ay = static_cast<float>(y - y0);
    const float w[4] = {(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
    const float tol = static_cast<float>(depth_tolerance * p.z());
    const float z = static_cast<float>(p.z());
    cv::Vec3f sum(0, 0, 0);
    float wsum = 0.0f;
    for (int k = 0; k < 4; ++k) {
      if (w[k] <= 0.0f) continue;
      const int tx = x0 + (k & 1), ty = y0 + (k >> 1);
      if (tx < 0 || ty < 0 || tx >= frame.cols || ty >= frame.rows) continue;
      if (fail_safe) {
        const int gx = tx - guard_rect.x, gy = ty - guard_rect.y;
        if (gx < 0 || gy < 0 || gx >= guard_rect.width || gy >= guard_rect.height) continue;
        const size_t g = static_cast<size_t>(gy) * guard.width + gx;
        const int id = guard.triangle[g];
        if (id < 0) continue;
        if (id != tri && std::abs(guard.depth[g] - z) > tol) continue;
        if (extra_mask && extra_mask->ptr<std::uint8_t>(ty)[tx]) continue;
      }
      const cv::Vec3b& c = frame.ptr<cv::Vec3b>(ty)[tx];
      sum += w[k] * cv::Vec3f(c[0], c[1], c[2]);
      wsum += w[k];
    }
    if (wsum <= 0.0f) return false;
    out = sum * (1.0f / wsum);
    return true;
  }

  /// Fail-safe colour: barycentric interpolation of the vertex colours.
  cv::Vec3f fill(int tri, float u, float v) const {
    const auto t = triangles.row(tri);
    return (1.0f - u - v) * vertex_colors[t(0)] + u * vertex_colors[t(1)] + v * vertex_colors[t(2)];
  }

  /// Colour of the simulated sample (tri, u, v); counts fail-safe and rejected samples.
  cv::Vec3f shade(int tri, float u, float v, std::int64_t& fallback, std::int64_t& rejected) const {
    if (interior[tri]) return interior_color;
    if (observed[tri] || !fail_safe) {
      cv::Vec3f c;
      if (sample(tri, aligned_point(tri, u, v), c)) return c;
      rejected += observed[tri] ? 1 : 0;
    }
    ++fallback;
    return fill(tri, u, v);
  }
};

}  // namespace

cv::Rect projected_bounds(const Vertices& cam_vertices, const Camera& camera, int margin_px) {
  const cv::Rect image(0, 0, camera.width, camera.height);
  if (cam_vertices.rows() == 0) return {};
  double x_min = HUGE_VAL, y_min = HUGE_VAL, x_max = -HUGE_VAL, y_max = -HUGE_VAL;
  for (Eigen::Index i = 0; i < cam_vertices.rows(); ++i) {
    const double z = cam_vertices(i, 2);
    if (!(z > 1e-12)) return image;
    const double x = camera.fx * cam_vertices(i, 0) / z + camera.cx;
    const double y = camera.fy * cam_vertices(i, 1) / z + camera.cy;
    x_min = std::min(x_min, x);
    x_max = std::max(x_max, x);
    y_min = std::min(y_min, y);
    y_max = std::max(y_max, y);
  }
  // Keep the arithmetic in double until the rectangle is clipped (far-off projections).
  const double lo_x = std::max(std::floor(x_min) - margin_px, 0.0);
  const double lo_y = std::max(std::floor(y_min) - margin_px, 0.0);
  const double hi_x = std::min(std::ceil(x_max) + margin_px + 1.0, double(camera.width));
  const double hi_y = std::min(std::ceil(y_max) + margin_px + 1.0, double(camera.height));
  if (!(hi_x > lo_x && hi_y > lo_y)) return {};
  return cv::Rect(static_cast<int>(lo_x), static_cast<int>(lo_y), static_cast<int>(hi_x - lo_x),
                  static_cast<int>(hi_y - lo_y));
}

Eigen::Vector3d surface_centroid(const Vertices& vertices, const Triangles& triangles) {
  check_triangle_indices(triangles, vertices.rows(), "surface_centroid");
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  double area = 0.0;
  for (Eigen::Index j = 0; j < triangles.rows(); ++j) {
    const Eigen::Vector3d a = vertices.row(triangles(j, 0)).transpose();
    const Eigen::Vector3d b = vertices.row(triangles(j, 1)).transpose();
    const Eigen::Vector3d c = vertices.row(triangles(j, 2)).transpose();
    const double aj = 0.5 * (b - a).cross(c - a).norm();
    sum += aj * (a + b + c) / 3.0;
    area += aj;
  }
  if (area > 0.0) return sum / area;
  if (vertices.rows() == 0) return Eigen::Vector3d::Zero();
  return vertices.colwise().mean().transpose();
}

void silhouette_mask(RayScene& scene, const Vertices& cam_vertices, const Camera& camera,
                     double scale, int dilate_px, cv::Mat& mask) {
  if (!(scale > 0.0) || dilate_px < 0)
    throw InputError("silhouette_mask(): scale must be > 0 and dilate_px >= 0");
  mask.create(camera.height, camera.width, CV_8U);
  mask.setTo(0);
  Vertices scaled = cam_vertices;
  if (scale != 1.0) {
    const Eigen::RowVector3d c = surface_centroid(cam_vertices, scene.triangles()).transpose();
    scaled = ((cam_vertices.rowwise() - c) * scale).rowwise() + c;
  }
  scene.update(scaled);
  const cv::Rect r = projected_bounds(scaled, camera, 1);
  if (r.area() <= 0) return;
  PrimaryHits hits;
  cast_rect(scene, camera, r, hits);
  for (int y = 0; y < r.height; ++y) {
    std::uint8_t* row = mask.ptr<std::uint8_t>(r.y + y) + r.x;
    const std::int32_t* tri = hits.triangle.data() + static_cast<size_t>(y) * hits.width;
    for (int x = 0; x < r.width; ++x) row[x] = tri[x] >= 0 ? 255 : 0;
  }
  // Dilating by the image diagonal or more covers the whole image (a kernel that large would
  // take minutes, and its rectangle could overflow int).
  if (static_cast<double>(dilate_px) >= std::hypot(camera.width, camera.height)) {
    if (cv::countNonZero(mask) > 0) mask.setTo(255);
    return;
  }
  if (dilate_px > 0) {
    const cv::Rect grown = cv::Rect(r.x - dilate_px, r.y - dilate_px, r.width + 2 * dilate_px,
                                    r.height + 2 * dilate_px) &
                           cv::Rect(0, 0, camera.width, camera.height);
    const cv::Mat kernel = cv::getStructuringElement(
        cv::MORPH_ELLIPSE, cv::Size(2 * dilate_px + 1, 2 * dilate_px + 1));
    cv::Mat roi = mask(grown);
    cv::dilate(roi, roi, kernel, cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  }
}

cv::Mat silhouette_mask(const Triangles& triangles, const Vertices& cam_vertices,
                        const Camera& camera, double scale, int dilate_px) {
  RayScene scene(cam_vertices, triangles);
  cv::Mat mask;
  silhouette_mask(scene, cam_vertices, camera, scale, dilate_px, mask);
  return mask;
}

struct Renderer::Impl {
  Camera camera;
  RenderOptions options;
  Triangles triangles;
  std::vector<std::uint8_t> interior;  // #F
  int nv = 0, nf = 0;
  VertexGraph graph;

  RayScene aligned_scene, scaled_scene, sim_scene;
  PrimaryHits aligned_hits, sim_hits;
  cv::Rect aligned_rect, sim_rect, last_fg_rect;

  std::vector<cv::Vec3f> corner_colors;  // 3 #F
  std::vector<std::uint8_t> corner_ok;   // 3 #F
  std::vector<cv::Vec3f> vertex_colors;  // #V
  std::vector<float> vertex_weight;      // #V
  std::vector<std::uint8_t> vertex_known;
  std::vector<std::uint8_t> observed_auto;  // #F, for the render() overload without v_j
  std::vector<std::uint8_t> edge;           // sim_rect pixels: 1 = supersample
  std::vector<int> edge_pixels;             // indices into sim_rect
  Eigen::MatrixX3d ray_origins, ray_directions;

  cv::Mat foreground, matte, removal;
  RenderStats stats;

  void render(const cv::Mat& input, const Vertices& aligned, const Vertices& simulated,
              const std::vector<std::uint8_t>& observed, const cv::Mat& plate,
              const cv::Mat& extra_mask, cv::Mat& output);
  /// Largest displacement (pixels) of a vertex's projection when `aligned` is enlarged by
  /// options.scale about its surface centroid; +infinity when a vertex is not in front of the
  /// camera.
  double enlargement_px(const Vertices& aligned) const {
    const Eigen::Vector3d c = surface_centroid(aligned, triangles);
    double reach = 0.0;
    for (Eigen::Index i = 0; i < aligned.rows(); ++i) {
      const Eigen::Vector3d p = aligned.row(i).transpose();
      const Eigen::Vector3d q = c + options.scale * (p - c);
      if (!(p.z() > 1e-9) || !(q.z() > 1e-9)) return HUGE_VAL;
      reach = std::max(reach, (camera.project(q) - camera.project(p)).norm());
    }
    return reach;
  }
  void compute_vertex_colors(const Shader& shader, const std::vector<std::uint8_t>& observed);
  void shade_pixels(const Shader& shader, Counters& counters);
  void shade_edges(const Shader& shader, Counters& counters);
};

Renderer::Renderer(const Mesh& mesh, const Camera& camera, RenderOptions options)
    : m_impl(std::make_unique<Impl>()) {
  camera.validate();
  if (options.supersample < 1 || options.supersample > 8)
    throw InputError("supersample must be in [1, 8], got " + std::to_string(options.supersample));
  if (!(options.scale > 0.0) || !std::isfinite(options.scale))
    throw InputError("scale must be positive, got " + std::to_string(options.scale));
  if (options.dilate_px < 0) throw InputError("dilate_px must be >= 0");
  if (!(options.depth_tolerance >= 0.0) || !(options.edge_depth_jump > 0.0))
    throw InputError("depth_tolerance must be >= 0 and edge_depth_jump > 0");
  if (!(options.interior_shade >= 0.0)) throw InputError("interior_shade must be >= 0");
  if (options.fill_smoothing_sweeps < 0) throw InputError("fill_smoothing_sweeps must be >= 0");
  Impl& m = *m_impl;
  m.camera = camera;
  m.options = options;
  m.triangles = mesh.triangles;
  m.nv = mesh.num_vertices();
  m.nf = mesh.num_triangles();
  m.interior = mesh.interior;
  if (m.interior.empty()) m.interior.assign(static_cast<size_t>(m.nf), 0);
  if (static_cast<int>(m.interior.size()) != m.nf)
    throw InputError("mesh has " + std::to_string(m.nf) + " triangles but " +
                     std::to_string(m.interior.size()) + " interior flags");
  m.graph = VertexGraph::from_triangles(mesh.triangles, m.nv);
  m.aligned_scene.set_mesh(mesh.vertices, mesh.triangles);
  m.scaled_scene.set_mesh(mesh.vertices, mesh.triangles);
  m.sim_scene.set_mesh(mesh.vertices, mesh.triangles);
  m.corner_colors.resize(3 * static_cast<size_t>(m.nf));
  m.corner_ok.resize(3 * static_cast<size_t>(m.nf));
  m.vertex_colors.resize(static_cast<size_t>(m.nv));
  m.vertex_weight.resize(static_cast<size_t>(m.nv));
  m.vertex_known.resize(static_cast<size_t>(m.nv));
  m.foreground = cv::Mat::zeros(camera.height, camera.width, CV_32FC3);
  m.matte = cv::Mat::zeros(camera.height, camera.width, CV_32F);
  m.removal = cv::Mat::zeros(camera.height, camera.width, CV_8U);
}

Renderer::~Renderer() = default;
Renderer::Renderer(Renderer&&) noexcept = default;
Renderer& Renderer::operator=(Renderer&&) noexcept = default;

void Renderer::render(const cv::Mat& input_frame, const Vertices& aligned_cam,
                      const Vertices& simulated_cam,
                      const std::vector<std::uint8_t>& observed_in_input, const cv::Mat& plate,
                      const cv::Mat& extra_mask, cv::Mat& output) {
  m_impl->render(input_frame, aligned_cam, simulated_cam, observed_in_input, plate, extra_mask,
                 output);
}

cv::Mat Renderer::render(const cv::Mat& input_frame, const Vertices& aligned_cam,
                         const Vertices& simulated_cam,
                         const std::vector<std::uint8_t>& observed_in_input, const cv::Mat& plate,
                         const cv::Mat& extra_mask) {
  cv::Mat output;
  m_impl->render(input_frame, aligned_cam, simulated_cam, observed_in_input, plate, extra_mask,
                 output);
  return output;
}

cv::Mat Renderer::render(const cv::Mat& input_frame, const Vertices& aligned_cam,
                         const Vertices& simulated_cam, const cv::Mat& plate,
                         const cv::Mat& extra_mask) {
  Impl& m = *m_impl;
  check_vertices(aligned_cam, m.nv, "aligned vertices");
  m.observed_auto =
      compute_visibility(m.aligned_scene, aligned_cam, m.camera, m.options.visibility).visible;
  cv::Mat output;
  m.render(input_frame, aligned_cam, simulated_cam, m.observed_auto, plate, extra_mask, output);
  return output;
}

const cv::Mat& Renderer::foreground() const {
  return m_impl->foreground;
}
const cv::Mat& Renderer::matte() const {
  return m_impl->matte;
}
const cv::Mat& Renderer::removal_mask() const {
  return m_impl->removal;
}
const RenderStats& Renderer::stats() const {
  return m_impl->stats;
}
const RenderOptions& Renderer::options() const {
  return m_impl->options;
}
const Camera& Renderer::camera() const {
  return m_impl->camera;
}

void Renderer::Impl::compute_vertex_colors(const Shader& shader,
                                           const std::vector<std::uint8_t>& observed) {
  // Per observed exterior triangle, one sample near each corner (barycentric weight 0.6 on the
  // corner): inside the triangle, so away from the silhouette where input pixels are mixed.
  tbb::parallel_for(tbb::blocked_range<int>(0, nf, 1024), [&](const tbb::blocked_range<int>& r) {
    for (int j = r.begin(); j != r.end(); ++j) {
      for (int k = 0; k < 3; ++k) corner_ok[3 * j + k] = 0;
      if (!observed[j] || interior[j]) continue;
      for (int k = 0; k < 3; ++k) {
        const double w[3] = {k == 0 ? 0.6 : 0.2, k == 1 ? 0.6 : 0.2, k == 2 ? 0.6 : 0.2};
        const Eigen::Vector3d p = shader.aligned_point(j, w[1], w[2]);
        cv::Vec3f c;
        if (shader.sample(j, p, c)) {
          corner_colors[3 * j + k] = c;
          corner_ok[3 * j + k] = 1;
        }
      }
    }
  });
  std::fill(vertex_colors.begin(), vertex_colors.end(), cv::Vec3f(0, 0, 0));
  std::fill(vertex_weight.begin(), vertex_weight.end(), 0.0f);
  for (int j = 0; j < nf; ++j)
    for (int k = 0; k < 3; ++k)
      if (corner_ok[3 * j + k]) {
        const int vi = triangles(j, k);
        vertex_colors[vi] += corner_colors[3 * j + k];
        vertex_weight[vi] += 1.0f;
      }
  for (int i = 0; i < nv; ++i) {
    vertex_known[i] = vertex_weight[i] > 0.0f;
    if (vertex_known[i]) vertex_colors[i] *= 1.0f / vertex_weight[i];
  }
  stats.filled_vertices = fill_vertex_colors(
      graph, vertex_colors, vertex_known, options.fill_smoothing_sweeps, stats.object_mean_color);
}

void Renderer::Impl::shade_pixels(const Shader& shader, Counters& counters) {
  const cv::Rect r = sim_rect;
  const float jump = static_cast<float>(options.edge_depth_jump);
  const bool supersample = options.supersample > 1;
  edge.assign(static_cast<size_t>(r.area()), 0);
  tbb::parallel_for(
      tbb::blocked_range<int>(0, r.height, 8), [&](const tbb::blocked_range<int>& rows) {
        std::int64_t covered = 0, fallback = 0, rejected = 0;
        for (int y = rows.begin(); y != rows.end(); ++y) {
          cv::Vec3f* fg = foreground.ptr<cv::Vec3f>(r.y + y) + r.x;
          float* mt = matte.ptr<float>(r.y + y) + r.x;
          for (int x = 0; x < r.width; ++x) {
            const size_t i = static_cast<size_t>(y) * r.width + x;
            const int tri = sim_hits.triangle[i];
            const float d = sim_hits.depth[i];
            bool is_edge = false;
            if (supersample) {
              // 4-neighbourhood: a coverage change or a depth jump between neighbours marks the
              // pixels on both sides of a silhouette or occlusion edge.
              constexpr int kDx[4] = {1, -1, 0, 0}, kDy[4] = {0, 0, 1, -1};
              for (int k = 0; k < 4; ++k) {
                const int nx = x + kDx[k], ny = y + kDy[k];
                int ntri = -1;
                float nd = 0.0f;
                if (nx >= 0 && ny >= 0 && nx < r.width && ny < r.height) {
                  const size_t n = static_cast<size_t>(ny) * r.width + nx;
                  ntri = sim_hits.triangle[n];
                  nd = sim_hits.depth[n];
                }
                if ((ntri >= 0) != (tri >= 0) ||
                    (tri >= 0 && std::abs(nd - d) > jump * std::min(nd, d))) {
                  is_edge = true;
                  break;
                }
              }
            }
            if (is_edge) {
              edge[i] = 1;
            } else if (tri >= 0) {
              fg[x] = shader.shade(tri, sim_hits.u[i], sim_hits.v[i], fallback, rejected);
              mt[x] = 1.0f;
              ++covered;
            }
          }
        }
        counters.covered += covered;
        counters.fallback += fallback;
        counters.rejected += rejected;
      });
}

void Renderer::Impl::shade_edges(const Shader& shader, Counters& counters) {
  const cv::Rect r = sim_rect;
  edge_pixels.clear();
  for (size_t i = 0; i < edge.size(); ++i)
    if (edge[i]) edge_pixels.push_back(static_cast<int>(i));
  stats.edge_pixels = static_cast<std::int64_t>(edge_pixels.size());
  if (edge_pixels.empty()) return;
  const int s = options.supersample;
  const bool reuse_centre = (s % 2) == 1;  // the middle sub-sample is the pixel centre
  const int centre = reuse_centre ? (s / 2) * s + s / 2 : -1;
  const int rays_per_pixel = s * s - (reuse_centre ? 1 : 0);
  const Eigen::Index n = static_cast<Eigen::Index>(edge_pixels.size()) * rays_per_pixel;
  ray_origins.setZero(n, 3);
  ray_directions.resize(n, 3);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, edge_pixels.size(), 256),
                    [&](const tbb::blocked_range<size_t>& range) {
                      for (size_t e = range.begin(); e != range.end(); ++e) {
                        const int i = edge_pixels[e];
                        const double px = r.x + i % r.width, py = r.y + i / r.width;
                        Eigen::Index row = static_cast<Eigen::Index>(e) * rays_per_pixel;
                        for (int k = 0; k < s * s; ++k) {
                          if (k == centre) continue;
                          const double sx = px + (k % s + 0.5) / s - 0.5;
                          const double sy = py + (k / s + 0.5) / s - 0.5;
                          ray_directions(row, 0) = (sx - camera.cx) / camera.fx;
                          ray_directions(row, 1) = (sy - camera.cy) / camera.fy;
                          ray_directions(row, 2) = 1.0;
                          ++row;
                        }
                      }
                    });
  const std::vector<RayHit> hits = sim_scene.intersect(ray_origins, ray_directions);
  const float inv_samples = 1.0f / static_cast<float>(s * s);
  tbb::parallel_for(tbb::blocked_range<size_t>(0, edge_pixels.size(), 256),
                    [&](const tbb::blocked_range<size_t>& range) {
                      std::int64_t covered = 0, fallback = 0, rejected = 0;
                      for (size_t e = range.begin(); e != range.end(); ++e) {
                        const int i = edge_pixels[e];
                        cv::Vec3f sum(0, 0, 0);
                        int count = 0;
                        if (reuse_centre && sim_hits.triangle[i] >= 0) {
                          sum += shader.shade(sim_hits.triangle[i], sim_hits.u[i], sim_hits.v[i],
                                              fallback, rejected);
                          ++count;
                        }
                        const size_t base = e * static_cast<size_t>(rays_per_pixel);
                        for (int k = 0; k < rays_per_pixel; ++k) {
                          const RayHit& h = hits[base + k];
                          if (h.triangle < 0) continue;
                          sum += shader.shade(h.triangle, h.u, h.v, fallback, rejected);
                          ++count;
                        }
                        if (count == 0) continue;
                        const int x = r.x + i % r.width, y = r.y + i / r.width;
                        foreground.ptr<cv::Vec3f>(y)[x] = sum * (1.0f / static_cast<float>(count));
                        matte.ptr<float>(y)[x] = static_cast<float>(count) * inv_samples;
                        ++covered;
                      }
                      counters.covered += covered;
                      counters.fallback += fallback;
                      counters.rejected += rejected;
                    });
}

void Renderer::Impl::render(const cv::Mat& input, const Vertices& aligned,
                            const Vertices& simulated, const std::vector<std::uint8_t>& observed,
                            const cv::Mat& plate, const cv::Mat& extra_mask, cv::Mat& output) {
  check_image(input, CV_8UC3, camera, "input frame");
  check_image(plate, CV_8UC3, camera, "background plate");
  if (!extra_mask.empty()) check_image(extra_mask, CV_8UC1, camera, "extra mask");
  check_vertices(aligned, nv, "aligned vertices");
  check_vertices(simulated, nv, "simulated vertices");
  if (static_cast<int>(observed.size()) != nf)
    throw InputError("observed flags: expected " + std::to_string(nf) +
                     " (one per triangle), got " + std::to_string(observed.size()));
  stats = RenderStats{};

  // 1. The aligned mesh through the pixel centres: which surface point each input pixel shows.
  aligned_scene.update(aligned);
  aligned_rect = projected_bounds(aligned, camera, 1);
  cast_rect(aligned_scene, camera, aligned_rect, aligned_hits);

  // 2. The pixels to replace by the plate: the enlarged, dilated silhouette and the extra mask.
  //    Enlarging about the centroid moves vertex v's projection by d_v pixels; every pixel
  //    centre inside the enlarged silhouette therefore lies within max d_v (+ half a pixel
  //    diagonal, for the centre sampling of the silhouette) of a pixel centre inside the
  //    aligned silhouette, so dilating the aligned silhouette by that radius covers the
  //    enlarged one without casting it. The exact cast is the fallback for a mesh reaching
  //    behind the camera.
  {
    // Dilation by the largest displacement is exact enough for the displacements an enlargement
    // of about 1% gives (a few pixels); a vertex near the camera plane can move hundreds of
    // pixels, and a kernel that large costs seconds: the exact cast then.
    constexpr double max_reach_px = 32.0;
    const double reach = enlargement_px(aligned);
    if (std::isfinite(reach) && reach <= max_reach_px &&
        static_cast<double>(options.dilate_px) < std::hypot(camera.width, camera.height)) {
      removal.setTo(0);
      for (int y = 0; y < aligned_rect.height; ++y) {
        std::uint8_t* row = removal.ptr<std::uint8_t>(aligned_rect.y + y) + aligned_rect.x;
        const std::int32_t* tri =
            aligned_hits.triangle.data() + static_cast<size_t>(y) * aligned_hits.width;
        for (int x = 0; x < aligned_rect.width; ++x) row[x] = tri[x] >= 0 ? 255 : 0;
      }
      const int radius = options.dilate_px + static_cast<int>(std::ceil(reach + 0.75));
      const cv::Rect grown =
          cv::Rect(aligned_rect.x - radius, aligned_rect.y - radius,
                   aligned_rect.width + 2 * radius, aligned_rect.height + 2 * radius) &
          cv::Rect(0, 0, camera.width, camera.height);
      if (radius > 0 && grown.area() > 0) {
        cv::Mat roi = removal(grown);
        cv::dilate(
            roi, roi,
            cv::getStructuringElement(cv::MORPH_ELLIPSE, cv::Size(2 * radius + 1, 2 * radius + 1)),
            cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
      }
    } else {
      silhouette_mask(scaled_scene, aligned, camera, options.scale, options.dilate_px, removal);
    }
  }
  if (!extra_mask.empty()) {
    cv::Mat extra = extra_mask != 0;
    cv::bitwise_or(removal, extra, removal);
  }
  stats.removed_pixels = cv::countNonZero(removal);

  // 3. Mean colour of the object in the input frame, interior colour.
  {
    cv::Vec3d sum(0, 0, 0);
    std::int64_t count = 0;
    for (int y = 0; y < aligned_rect.height; ++y) {
      const cv::Vec3b* row = input.ptr<cv::Vec3b>(aligned_rect.y + y) + aligned_rect.x;
      const std::int32_t* tri =
          aligned_hits.triangle.data() + static_cast<size_t>(y) * aligned_hits.width;
      const std::uint8_t* hidden =
          extra_mask.empty() ? nullptr
                             : extra_mask.ptr<std::uint8_t>(aligned_rect.y + y) + aligned_rect.x;
      for (int x = 0; x < aligned_rect.width; ++x)
        if (tri[x] >= 0 && !(hidden && hidden[x])) {
          sum += cv::Vec3d(row[x][0], row[x][1], row[x][2]);
          ++count;
        }
    }
    // An object that is nowhere in the frame: mid grey rather than black.
    stats.object_mean_color = count > 0 ? cv::Vec3f(static_cast<float>(sum[0] / count),
                                                    static_cast<float>(sum[1] / count),
                                                    static_cast<float>(sum[2] / count))
                                        : cv::Vec3f(128, 128, 128);
    stats.interior_color = options.interior_color ? *options.interior_color
                                                  : stats.object_mean_color *
                                                        static_cast<float>(options.interior_shade);
  }
  for (int j = 0; j < nf; ++j) stats.unobserved_triangles += (!observed[j] && !interior[j]);

  const Shader shader{input,
                      camera,
                      aligned,
                      triangles,
                      observed.data(),
                      interior.data(),
                      aligned_hits,
                      aligned_rect,
                      vertex_colors.data(),
                      extra_mask.empty() ? nullptr : &extra_mask,
                      stats.interior_color,
                      options.fail_safe,
                      options.depth_tolerance};

  // 4. Fail-safe vertex colours.
  compute_vertex_colors(shader, observed);

  // 5. The simulated mesh: pixel centres, then sub-samples at edge pixels.
  if (last_fg_rect.area() > 0) {
    foreground(last_fg_rect).setTo(cv::Scalar::all(0));
    matte(last_fg_rect).setTo(cv::Scalar::all(0));
  }
  sim_scene.update(simulated);
  sim_rect = projected_bounds(simulated, camera, 2);
  cast_rect(sim_scene, camera, sim_rect, sim_hits);
  last_fg_rect = sim_rect;
  Counters counters;
  if (sim_rect.area() > 0) {
    shade_pixels(shader, counters);
    shade_edges(shader, counters);
  }
  stats.covered_pixels = counters.covered;
  stats.fallback_samples = counters.fallback;
  stats.rejected_samples = counters.rejected;

  // 6. Composite: input, plate where the original object (or the extra mask) was, the simulated
  //    object on top with its matte.
  input.copyTo(output);
  plate.copyTo(output, removal);
  if (sim_rect.area() > 0) {
    const cv::Rect r = sim_rect;
    tbb::parallel_for(
        tbb::blocked_range<int>(0, r.height, 16), [&](const tbb::blocked_range<int>& rows) {
          for (int y = rows.begin(); y != rows.end(); ++y) {
            cv::Vec3b* out = output.ptr<cv::Vec3b>(r.y + y) + r.x;
            const cv::Vec3f* fg = foreground.ptr<cv::Vec3f>(r.y + y) + r.x;
            const float* mt = matte.ptr<float>(r.y + y) + r.x;
            for (int x = 0; x < r.width; ++x) {
              const float a = mt[x];
              if (a <= 0.0f) continue;
              for (int c = 0; c < 3; ++c)
                out[x][c] = cv::saturate_cast<std::uint8_t>(a * fg[x][c] + (1.0f - a) * out[x][c]);
            }
          }
        });
  }
}

}  // namespace pbve
