// Uses pbve::core and pbve::mass_spring from an installed tree: builds a mesh, refines it,
// projects it, and lets it hang as cloth from one corner for a second.
#include <cstdio>

#include <pbve/config.hpp>
#include <pbve/core/camera.hpp>
#include <pbve/core/mesh.hpp>
#include <pbve/core/pose.hpp>
#include <pbve/mass_spring/mass_spring.hpp>

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
  // The refined triangle as cloth held at vertex 0, under gravity (+y) for 30 frames.
  pbve::mass_spring::MassSpringSimulator cloth(
      fine, {0}, pbve::mass_spring::Params::preset(pbve::mass_spring::Material::cloth));
  const double y0 = cloth.positions().col(1).mean();
  for (int frame = 0; frame < 30; ++frame) cloth.step({});
  const double drop = cloth.positions().col(1).mean() - y0;
  std::printf("pbve %s: %d -> %d triangles, vertex 1 at pixel (%.1f, %.1f), cloth dropped %.3f m\n",
              pbve::version_string, mesh.num_triangles(), fine.num_triangles(), px.x(), px.y(),
              drop);
  // 0.2 m at 1 m depth with fx = 600 lands 120 px right of the principal point. The cloth
  // hangs from vertex 0: its mean drops, by at most its size.
  return (fine.num_triangles() > mesh.num_triangles() && px.x() == 440.0 && drop > 0.01 &&
          drop < 0.2)
             ? 0
             : 1;
}
