#include "pbve/visibility/ray_scene.hpp"

#include <atomic>
#include <cmath>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <string>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "pbve/core/error.hpp"
#include "visibility/ray_scene_impl.hpp"

namespace pbve {
namespace {

// Embree reports errors through a callback; the message of the last one is kept here and
// turned into an exception by check_device().
thread_local std::string g_last_embree_error;

void embree_error(void* /*user*/, RTCError code, const char* message) {
  if (code == RTC_ERROR_NONE) return;
  g_last_embree_error = message ? message : "unknown Embree error";
}

std::shared_ptr<RTCDeviceTy> shared_device() {
  static std::mutex mutex;
  static std::weak_ptr<RTCDeviceTy> weak;
  std::lock_guard<std::mutex> lock(mutex);
  if (auto device = weak.lock()) return device;
  RTCDevice raw = rtcNewDevice(nullptr);
  if (!raw) throw std::runtime_error("Embree: could not create a device");
  rtcSetDeviceErrorFunction(raw, embree_error, nullptr);
  std::shared_ptr<RTCDeviceTy> device(raw, [](RTCDevice d) { rtcReleaseDevice(d); });
  weak = device;
  return device;
}

void check_device(RTCDevice device, const char* what) {
  const RTCError code = rtcGetDeviceError(device);
  if (code != RTC_ERROR_NONE) {
    std::string message = std::string("Embree error during ") + what;
    if (!g_last_embree_error.empty()) message += ": " + g_last_embree_error;
    g_last_embree_error.clear();
    throw std::runtime_error(message);
  }
}

void check_positions(const Vertices& vertices) {
  if (!vertices.allFinite()) {
    for (Eigen::Index i = 0; i < vertices.rows(); ++i)
      if (!vertices.row(i).allFinite())
        throw InputError("non-finite position", {}, 0, "vertex " + std::to_string(i));
  }
}

void copy_positions(const Vertices& vertices, float* buffer) {
  const Eigen::Index n = vertices.rows();
  tbb::parallel_for(tbb::blocked_range<Eigen::Index>(0, n, 4096),
                    [&](const tbb::blocked_range<Eigen::Index>& r) {
                      for (Eigen::Index i = r.begin(); i != r.end(); ++i)
                        for (int d = 0; d < 3; ++d)
                          buffer[3 * i + d] = static_cast<float>(vertices(i, d));
                    });
}

// Rays are checked while their packets are filled: a packet holding a ray Embree would abort on
// (detail::ray_component_ok() false) is skipped and its index kept here, the lowest of them, so
// that the query then names the same ray however the packets were scheduled.
void record_min(std::atomic<Eigen::Index>& lowest, Eigen::Index p) {
  Eigen::Index seen = lowest.load(std::memory_order_relaxed);
  while (p < seen && !lowest.compare_exchange_weak(seen, p, std::memory_order_relaxed)) {
  }
}

bool row_ok(const Eigen::Ref<const Eigen::MatrixX3d>& m, Eigen::Index i) {
  return detail::ray_component_ok(m(i, 0)) && detail::ray_component_ok(m(i, 1)) &&
         detail::ray_component_ok(m(i, 2));
}

// `what` followed by the row, e.g. "intersect(): ray 17: origin (nan, 0, 0) has a component
// ...", for a row failing row_ok().
InputError bad_ray(const std::string& what, const Eigen::Ref<const Eigen::MatrixX3d>& m,
                   Eigen::Index i) {
  std::ostringstream s;
  s << what << " (" << m(i, 0) << ", " << m(i, 1) << ", " << m(i, 2)
    << ") has a component that is not a number of magnitude at most " << detail::max_ray_component
    << ", the largest ray casting accepts";
  return InputError(s.str());
}

// Embree aborts on a NaN ray parameter too (infinities are fine).
void check_t(const char* function, const char* name, double t) {
  if (std::isnan(t))
    throw InputError(std::string(function) + ": " + name + " must be a number, got nan");
}

}  // namespace

std::int64_t PrimaryHits::hit_count() const {
  std::int64_t count = 0;
  for (std::int32_t t : triangle) count += (t >= 0);
  return count;
}

RayScene::Impl::Impl() : device(shared_device()) {}

RayScene::Impl::~Impl() {
  release();
}

void RayScene::Impl::release() {
  if (geometry) rtcReleaseGeometry(geometry);
  if (scene) rtcReleaseScene(scene);
  geometry = nullptr;
  scene = nullptr;
  vertex_buffer = nullptr;
}

void RayScene::Impl::commit() {
  rtcCommitScene(scene);
  check_device(device.get(), "scene commit");
}

void RayScene::Impl::build(const Vertices& v, const Triangles& t) {
  check_positions(v);
  const Eigen::Index nv = v.rows();
  for (Eigen::Index j = 0; j < t.rows(); ++j)
    for (int k = 0; k < 3; ++k)
      if (t(j, k) < 0 || t(j, k) >= nv)
        throw InputError("vertex index " + std::to_string(t(j, k)) + " out of range [0, " +
                             std::to_string(nv) + ")",
                         {}, 0, "triangle " + std::to_string(j));
  release();
  vertices = v;
  triangles = t;
  scene = rtcNewScene(device.get());
  rtcSetSceneFlags(scene, RTC_SCENE_FLAG_DYNAMIC | RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_LOW);
  if (t.rows() > 0) {
    geometry = rtcNewGeometry(device.get(), RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(geometry, RTC_BUILD_QUALITY_REFIT);
    vertex_buffer = static_cast<float*>(rtcSetNewGeometryBuffer(
        geometry, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float),
        static_cast<size_t>(std::max<Eigen::Index>(nv, 1))));
    auto* index_buffer = static_cast<unsigned*>(
        rtcSetNewGeometryBuffer(geometry, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                3 * sizeof(unsigned), static_cast<size_t>(t.rows())));
    check_device(device.get(), "buffer allocation");
    copy_positions(v, vertex_buffer);
    for (Eigen::Index j = 0; j < t.rows(); ++j)
      for (int k = 0; k < 3; ++k) index_buffer[3 * j + k] = static_cast<unsigned>(t(j, k));
    rtcCommitGeometry(geometry);
    rtcAttachGeometryByID(scene, geometry, 0);
  }
  commit();
}

void RayScene::Impl::refit(const Vertices& v, UpdateMode mode) {
  if (v.rows() != vertices.rows())
    throw InputError("update() got " + std::to_string(v.rows()) + " vertices, the scene has " +
                     std::to_string(vertices.rows()));
  check_positions(v);
  if (mode == UpdateMode::rebuild) {
    Triangles t = triangles;
    build(v, t);
    return;
  }
  vertices = v;
  if (!geometry) return;
  copy_positions(v, vertex_buffer);
  rtcUpdateGeometryBuffer(geometry, RTC_BUFFER_TYPE_VERTEX, 0);
  rtcCommitGeometry(geometry);
  commit();
}

RayScene::RayScene() : m_impl(std::make_unique<Impl>()) {
  m_impl->build(Vertices(0, 3), Triangles(0, 3));
}

RayScene::RayScene(const Vertices& vertices, const Triangles& triangles)
    : m_impl(std::make_unique<Impl>()) {
  m_impl->build(vertices, triangles);
}

RayScene::~RayScene() = default;
RayScene::RayScene(RayScene&&) noexcept = default;
RayScene& RayScene::operator=(RayScene&&) noexcept = default;

void RayScene::set_mesh(const Vertices& vertices, const Triangles& triangles) {
  m_impl->build(vertices, triangles);
}

void RayScene::update(const Vertices& vertices, UpdateMode mode) {
  m_impl->refit(vertices, mode);
}

int RayScene::num_vertices() const {
  return static_cast<int>(m_impl->vertices.rows());
}
int RayScene::num_triangles() const {
  return static_cast<int>(m_impl->triangles.rows());
}
const Vertices& RayScene::vertices() const {
  return m_impl->vertices;
}
const Triangles& RayScene::triangles() const {
  return m_impl->triangles;
}

std::vector<RayHit> RayScene::intersect(const Eigen::Ref<const Eigen::MatrixX3d>& origins,
                                        const Eigen::Ref<const Eigen::MatrixX3d>& directions,
                                        double t_min, double t_max) const {
  if (origins.rows() != directions.rows())
    throw InputError("intersect(): " + std::to_string(origins.rows()) + " origins but " +
                     std::to_string(directions.rows()) + " directions");
  check_t("intersect()", "t_min", t_min);
  check_t("intersect()", "t_max", t_max);
  const Eigen::Index n = origins.rows();
  std::vector<RayHit> hits(static_cast<size_t>(n));
  const float tn = static_cast<float>(t_min);
  const float tf = static_cast<float>(std::min<double>(t_max, std::numeric_limits<float>::max()));
  std::atomic<Eigen::Index> first_bad{n};  // lowest index of a packet with a refused ray
  tbb::parallel_for(tbb::blocked_range<Eigen::Index>(0, (n + 15) / 16, 16),
                    [&](const tbb::blocked_range<Eigen::Index>& r) {
                      RTCIntersectContext context;
                      rtcInitIntersectContext(&context);
                      alignas(64) RTCRayHit16 packet;
                      alignas(64) int valid[16];
                      for (Eigen::Index p = r.begin(); p != r.end(); ++p) {
                        bool ok = true;
                        for (int k = 0; k < 16; ++k) {
                          const Eigen::Index i = std::min<Eigen::Index>(16 * p + k, n - 1);
                          valid[k] = (16 * p + k < n) ? -1 : 0;
                          const double ox = origins(i, 0), oy = origins(i, 1), oz = origins(i, 2);
                          const double dx = directions(i, 0), dy = directions(i, 1),
                                       dz = directions(i, 2);
                          // Bitwise &: six comparisons without branches.
                          ok = ok & detail::ray_component_ok(ox) & detail::ray_component_ok(oy) &
                               detail::ray_component_ok(oz) & detail::ray_component_ok(dx) &
                               detail::ray_component_ok(dy) & detail::ray_component_ok(dz);
                          packet.ray.org_x[k] = static_cast<float>(ox);
                          packet.ray.org_y[k] = static_cast<float>(oy);
                          packet.ray.org_z[k] = static_cast<float>(oz);
                          packet.ray.dir_x[k] = static_cast<float>(dx);
                          packet.ray.dir_y[k] = static_cast<float>(dy);
                          packet.ray.dir_z[k] = static_cast<float>(dz);
                          packet.ray.tnear[k] = tn;
                          packet.ray.tfar[k] = tf;
                          packet.ray.time[k] = 0.0f;
                          packet.ray.mask[k] = 0xFFFFFFFFu;
                          packet.ray.id[k] = static_cast<unsigned>(k);
                          packet.ray.flags[k] = 0;
                          packet.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID;
                        }
                        if (!ok) {  // Embree would abort: skip the packet, throw below
                          record_min(first_bad, p);
                          continue;
                        }
                        rtcIntersect16(valid, m_impl->scene, &context, &packet);
                        for (int k = 0; k < 16 && 16 * p + k < n; ++k) {
                          RayHit& h = hits[static_cast<size_t>(16 * p + k)];
                          if (packet.hit.geomID[k] == RTC_INVALID_GEOMETRY_ID) continue;
                          h.triangle = static_cast<std::int32_t>(packet.hit.primID[k]);
                          h.u = packet.hit.u[k];
                          h.v = packet.hit.v[k];
                          h.t = packet.ray.tfar[k];
                        }
                      }
                    });
  if (first_bad.load() < n) {
    for (Eigen::Index i = 16 * first_bad.load(); i < n; ++i) {
      const std::string ray = "intersect(): ray " + std::to_string(i);
      if (!row_ok(origins, i)) throw bad_ray(ray + ": origin", origins, i);
      if (!row_ok(directions, i)) throw bad_ray(ray + ": direction", directions, i);
    }
  }
  return hits;
}

std::vector<std::uint8_t> RayScene::occluded_from_origin(
    const Eigen::Ref<const Eigen::MatrixX3d>& targets, double t_max) const {
  check_t("occluded_from_origin()", "t_max", t_max);
  const Eigen::Index n = targets.rows();
  std::vector<std::uint8_t> result(static_cast<size_t>(n), 0);
  const float tf = static_cast<float>(t_max);
  std::atomic<Eigen::Index> first_bad{n};  // lowest index of a packet with a refused ray
  tbb::parallel_for(tbb::blocked_range<Eigen::Index>(0, (n + 15) / 16, 16),
                    [&](const tbb::blocked_range<Eigen::Index>& r) {
                      RTCIntersectContext context;
                      rtcInitIntersectContext(&context);
                      alignas(64) RTCRay16 packet;
                      alignas(64) int valid[16];
                      for (Eigen::Index p = r.begin(); p != r.end(); ++p) {
                        bool ok = true;
                        for (int k = 0; k < 16; ++k) {
                          const Eigen::Index i = std::min<Eigen::Index>(16 * p + k, n - 1);
                          valid[k] = (16 * p + k < n) ? -1 : 0;
                          const double x = targets(i, 0), y = targets(i, 1), z = targets(i, 2);
                          ok = ok & detail::ray_component_ok(x) & detail::ray_component_ok(y) &
                               detail::ray_component_ok(z);
                          packet.org_x[k] = packet.org_y[k] = packet.org_z[k] = 0.0f;
                          packet.dir_x[k] = static_cast<float>(x);
                          packet.dir_y[k] = static_cast<float>(y);
                          packet.dir_z[k] = static_cast<float>(z);
                          packet.tnear[k] = 0.0f;
                          packet.tfar[k] = tf;
                          packet.time[k] = 0.0f;
                          packet.mask[k] = 0xFFFFFFFFu;
                          packet.id[k] = static_cast<unsigned>(k);
                          packet.flags[k] = 0;
                        }
                        if (!ok) {  // Embree would abort: skip the packet, throw below
                          record_min(first_bad, p);
                          continue;
                        }
                        rtcOccluded16(valid, m_impl->scene, &context, &packet);
                        for (int k = 0; k < 16 && 16 * p + k < n; ++k)
                          result[static_cast<size_t>(16 * p + k)] = packet.tfar[k] < 0.0f;
                      }
                    });
  if (first_bad.load() < n) {
    for (Eigen::Index i = 16 * first_bad.load(); i < n; ++i)
      if (!row_ok(targets, i))
        throw bad_ray("occluded_from_origin(): target " + std::to_string(i), targets, i);
  }
  return result;
}

PrimaryHits RayScene::cast_primary(const Camera& camera, int supersample) const {
  detail::check_ray_camera(camera, "cast_primary()");
  detail::check_primary_rays(camera, supersample, "cast_primary()");
  PrimaryHits hits;
  hits.supersample = supersample;
  hits.width = camera.width * supersample;
  hits.height = camera.height * supersample;
  const size_t n = static_cast<size_t>(hits.width) * static_cast<size_t>(hits.height);
  hits.triangle.assign(n, -1);
  hits.u.assign(n, 0.0f);
  hits.v.assign(n, 0.0f);
  hits.depth.assign(n, std::numeric_limits<float>::infinity());
  const int w = hits.width;
  int no_local = 0;
  detail::for_each_primary(
      *m_impl, camera, supersample, [&]() -> int& { return no_local; },
      [&](int&, int x, int y, int tri, float u, float v, float depth, float) {
        const size_t i = static_cast<size_t>(y) * w + x;
        hits.triangle[i] = tri;
        hits.u[i] = u;
        hits.v[i] = v;
        hits.depth[i] = depth;
      });
  return hits;
}

}  // namespace pbve
