// Uses pbve::core from an installed tree: builds a mesh, refines it, projects it.
#include <cstdio>

#include <pbve/config.hpp>
#include <pbve/core/camera.hpp>
#include <pbve/core/mesh.hpp>
#include <pbve/core/pose.hpp>

int main() {
  pbve::Mesh mesh;
  mesh.vertices.resize(3, 3);
  mesh.vertices << 0, 0, 0, 0.2, 0, 0, 0, 0.2, 0;
  mesh.triangles.resize(1, 3);
  mesh.triangles << 0, 1, 2;
  mesh.triangle_part = {0};
  mesh.part_names = {"default"};
  mesh.interior = {0};
  const pbve::Mesh fine = pbve::refine_mesh(mesh, 0.05);
  const pbve::Pose pose = pbve::Pose::from_rodrigues({0, 0, 0}, {0, 0, 1});
  const pbve::Camera camera;
  const Eigen::Vector2d px = camera.project(pose.apply(Eigen::Vector3d(0.2, 0, 0)));
  std::printf("pbve %s: %d -> %d triangles, vertex 1 at pixel (%.1f, %.1f)\n", pbve::version_string,
              mesh.num_triangles(), fine.num_triangles(), px.x(), px.y());
  // 0.2 m at 1 m depth with fx = 600 lands 120 px right of the principal point.
  return (fine.num_triangles() > mesh.num_triangles() && px.x() == 440.0) ? 0 : 1;
}
