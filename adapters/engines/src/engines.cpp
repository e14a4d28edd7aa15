#include "pbve/engines.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "pbve/core/error.hpp"

#ifdef PBVE_ENGINE_MASS_SPRING
#include "pbve/mass_spring/mass_spring.hpp"
#endif
#ifdef PBVE_ENGINE_BULLET
#include "pbve/bullet/bullet.hpp"
#endif

namespace pbve {

namespace {

[[noreturn]] void fail_key(const EngineRecipe& r, const std::string& key, int line,
                           const std::string& message) {
  throw InputError(message, r.scene_file, line, "key 'simulation." + key + "'");
}

/// Stores the `simulation:` parameter `key` into the field found for it, or fails naming the
/// key, its line and the nearest valid name; integer fields reject fractional values.
void store_parameter(const EngineRecipe& r, const std::string& engine, const std::string& key,
                     int line, double value, double* field, int* int_field) {
  if (!field && !int_field) {
    const auto names = engine_parameters(engine);
    std::string msg = "unknown key for engine " + engine;
    std::vector<std::string> candidates = names;  // a misspelt section key too (`substep`)
    candidates.insert(candidates.end(), kSimulationKeys.begin(), kSimulationKeys.end());
    const std::string near = nearest_key(key, candidates);
    if (!near.empty()) msg += " (did you mean '" + near + "'?)";
    msg += "; material parameters:";
    for (const auto& n : names) msg += " " + n;
    fail_key(r, key, line, msg);
  }
  if (field) *field = value;
  if (int_field) {
    if (value != std::trunc(value)) fail_key(r, key, line, "expected an integer");
    // (Converting a value beyond int's range would be undefined.)
    if (!(std::abs(value) <= static_cast<double>(std::numeric_limits<int>::max()))) {
      std::ostringstream text;
      text << "expected an integer, got one too large: " << value;
      fail_key(r, key, line, text.str());
    }
    *int_field = static_cast<int>(value);
  }
}

/// The materials an engine's parameter applies to, where not all of the engine's: set for
/// another material, the value would be silently ignored (a cloth has no interior lattice, a
/// rigid body no links), so the scene is refused naming the key, its line and the materials.
/// Empty for a key that applies to every material.
std::vector<std::string> materials_of(const std::string& engine, const std::string& key) {
  using List = std::vector<std::string>;
  const List cloth = {"cloth"}, solids = {"elastic", "stiff"}, soft = {"cloth", "elastic", "stiff"},
             rigid = {"rigid"};
  if (key == "single_sheet" || key == "layer_stiffness" || key == "layer_distance") return cloth;
  if (engine == "mass_spring") {
    if (key == "direct_solver_max_dofs_layered") return cloth;
    if (key == "volume_stiffness" || key == "lattice_spacing") return solids;
  }
  if (engine == "bullet") {
    if (key == "linear_stiffness" || key == "bending_stiffness" || key == "damping" ||
        key == "position_iterations")
      return soft;
    if (key == "shape_matching" || key == "volume_stiffness" || key == "pressure") return solids;
    if (key == "linear_damping" || key == "angular_damping" || key == "restitution" ||
        key == "hull_tolerance")
      return rigid;
  }
  return {};
}

/// Fails when the `simulation:` parameter `key` does not apply to `material` (materials_of()).
void check_applies(const EngineRecipe& r, const std::string& engine, const std::string& material,
                   const std::string& key, int line) {
  const std::vector<std::string> only = materials_of(engine, key);
  if (only.empty() || std::find(only.begin(), only.end(), material) != only.end()) return;
  std::string list;
  for (size_t i = 0; i < only.size(); ++i)
    list += (i == 0 ? "" : i + 1 == only.size() ? " and " : ", ") + only[i];
  fail_key(r, key, line,
           "applies to material " + list + " only, not to " + material + " (engine " + engine +
               "): the value would be ignored; remove the key");
}

#ifdef PBVE_ENGINE_MASS_SPRING
/// An adapter's invalid_argument as an InputError about the scene file, naming the engine once.
InputError mass_spring_error(const std::invalid_argument& e, const EngineRecipe& r) {
  const std::string what = e.what();  // the adapter's messages mostly name it already
  return InputError(what.rfind("mass_spring: ", 0) == 0 ? what : "mass_spring: " + what,
                    r.scene_file);
}

/// The recipe's mass_spring parameters, validated (no mesh needed).
mass_spring::Params mass_spring_params(const EngineRecipe& r) {
  namespace ms = mass_spring;
  const SceneSimulation& s = r.simulation;
  if (s.material == "rigid")
    fail_key(r, "material", 0,
             "the mass_spring engine has no rigid material: use 'stiff' (nearly rigid), or "
             "engine: bullet for rigid bodies");
  ms::Params p = ms::Params::preset(ms::material_from_string(s.material));
  p.gravity = s.gravity;
  p.substeps = s.substeps;
  auto plane = [](const ScenePlane& q) {
    ms::Plane out;
    out.point = q.point;
    out.normal = q.normal;
    out.friction = q.friction;
    return out;
  };
  if (s.ground) p.planes.push_back(plane(*s.ground));
  for (const auto& q : s.planes) p.planes.push_back(plane(q));
  for (const auto& [key, value_line] : s.parameters) {
    const auto [value, line] = value_line;
    double* field = nullptr;
    int* int_field = nullptr;
    if (key == "density")
      field = &p.density;
    else if (key == "stretch_stiffness")
      field = &p.stretch_stiffness;
    else if (key == "shear_stiffness")
      field = &p.shear_stiffness;
    else if (key == "bend_stiffness")
      field = &p.bend_stiffness;
    else if (key == "layer_stiffness")
      field = &p.layer_stiffness;
    else if (key == "layer_distance")
      field = &p.layer_distance;
    else if (key == "volume_stiffness")
      field = &p.volume_stiffness;
    else if (key == "lattice_spacing")
      field = &p.lattice_spacing;
    else if (key == "damping_alpha")
      field = &p.damping_alpha;
    else if (key == "damping_beta")
      field = &p.damping_beta;
    else if (key == "contact_stiffness")
      field = &p.contact_stiffness;
    else if (key == "friction_velocity")
      field = &p.friction_velocity;
    else if (key == "newton_tolerance")
      field = &p.newton_tolerance;
    else if (key == "newton_iterations")
      int_field = &p.newton_iterations;
    else if (key == "direct_solver_max_dofs")
      int_field = &p.direct_solver_max_dofs;
    else if (key == "direct_solver_max_dofs_layered")
      int_field = &p.direct_solver_max_dofs_layered;
    else if (key == "single_sheet")
      int_field = &p.single_sheet;
    store_parameter(r, "mass_spring", key, line, value, field, int_field);
    check_applies(r, "mass_spring", s.material, key, line);
  }
  for (const SceneRegion& g : s.regions) {
    ms::StiffnessRegion region;
    region.min = g.box_min;
    region.max = g.box_max;
    for (const auto& [key, value_line] : g.parameters) {
      if (key != "volume_stiffness")
        fail_key(r, "regions." + key, value_line.second,
                 "unknown region parameter for engine mass_spring (a region sets "
                 "volume_stiffness)");
      if (!(value_line.first > 0.0))
        fail_key(r, "regions." + key, value_line.second,
                 "must be positive (Pa), found " + std::to_string(value_line.first));
      region.volume_stiffness = value_line.first;
    }
    p.regions.push_back(region);
  }
  if (!s.regions.empty() && p.material == ms::Material::cloth)
    fail_key(r, "regions", s.regions.front().line,
             "regions apply to solids (material elastic or stiff), not to cloth");
  try {
    p.validate();
  } catch (const std::invalid_argument& e) {
    throw mass_spring_error(e, r);
  }
  return p;
}

std::unique_ptr<Simulator> make_mass_spring(const EngineRecipe& r) {
  const mass_spring::Params p = mass_spring_params(r);
  try {
    return std::make_unique<mass_spring::MassSpringSimulator>(r.mesh, r.rest_positions, r.anchors,
                                                              p);
  } catch (const InputError&) {
    throw;
  } catch (const std::invalid_argument& e) {
    throw mass_spring_error(e, r);
  }
}
#endif

#ifdef PBVE_ENGINE_BULLET
/// The recipe's Bullet parameters, validated (no mesh needed).
bullet::Params bullet_params(const EngineRecipe& r) {
  namespace bt = bullet;
  const SceneSimulation& s = r.simulation;
  bt::Material material;
  try {
    material = bt::material_from_string(s.material);
  } catch (const std::invalid_argument& e) {
    fail_key(r, "material", 0, e.what());
  }
  bt::Params p = bt::Params::preset(material);
  p.gravity = s.gravity;
  p.substeps = s.substeps;
  auto plane = [](const ScenePlane& q) {
    bt::Plane out;
    out.point = q.point;
    out.normal = q.normal;
    out.friction = q.friction;
    return out;
  };
  if (s.ground) p.planes.push_back(plane(*s.ground));
  for (const auto& q : s.planes) p.planes.push_back(plane(q));
  for (const auto& [key, value_line] : s.parameters) {
    const auto [value, line] = value_line;
    double* field = nullptr;
    int* int_field = nullptr;
    if (key == "density")
      field = &p.density;
    else if (key == "linear_stiffness")
      field = &p.linear_stiffness;
    else if (key == "bending_stiffness")
      field = &p.bending_stiffness;
    else if (key == "layer_stiffness")
      field = &p.layer_stiffness;
    else if (key == "layer_distance")
      field = &p.layer_distance;
    else if (key == "shape_matching")
      field = &p.shape_matching;
    else if (key == "volume_stiffness")
      field = &p.volume_stiffness;
    else if (key == "pressure")
      field = &p.pressure;
    else if (key == "damping")
      field = &p.damping;
    else if (key == "friction")
      field = &p.friction;
    else if (key == "collision_margin")
      field = &p.collision_margin;
    else if (key == "linear_damping")
      field = &p.linear_damping;
    else if (key == "angular_damping")
      field = &p.angular_damping;
    else if (key == "restitution")
      field = &p.restitution;
    else if (key == "hull_tolerance")
      field = &p.hull_tolerance;
    else if (key == "position_iterations")
      int_field = &p.position_iterations;
    else if (key == "single_sheet")
      int_field = &p.single_sheet;
    store_parameter(r, "bullet", key, line, value, field, int_field);
    check_applies(r, "bullet", s.material, key, line);
  }
  if (!s.regions.empty())
    fail_key(r, "regions", s.regions.front().line,
             "the bullet engine has one material per object; regions need engine mass_spring");
  try {
    p.validate();
  } catch (const std::invalid_argument& e) {
    throw InputError(e.what(), r.scene_file);
  }
  return p;
}

std::unique_ptr<Simulator> make_bullet(const EngineRecipe& r) {
  const bullet::Params p = bullet_params(r);
  try {
    return std::make_unique<bullet::BulletSimulator>(r.mesh, r.rest_positions, r.anchors, p);
  } catch (const InputError&) {
    throw;
  } catch (const std::invalid_argument& e) {
    throw InputError(e.what(), r.scene_file);
  }
}
#endif

}  // namespace

std::vector<std::string> available_engines() {
  std::vector<std::string> out;
#ifdef PBVE_ENGINE_MASS_SPRING
  out.push_back("mass_spring");
#endif
#ifdef PBVE_ENGINE_BULLET
  out.push_back("bullet");
#endif
  return out;
}

std::vector<std::string> engine_parameters(const std::string& engine) {
  if (engine == "mass_spring")
    return {"density",
            "stretch_stiffness",
            "shear_stiffness",
            "bend_stiffness",
            "layer_stiffness",
            "layer_distance",
            "volume_stiffness",
            "lattice_spacing",
            "damping_alpha",
            "damping_beta",
            "contact_stiffness",
            "friction_velocity",
            "newton_iterations",
            "newton_tolerance",
            "direct_solver_max_dofs",
            "direct_solver_max_dofs_layered",
            "single_sheet"};
  if (engine == "bullet")
    return {"density",         "linear_stiffness", "bending_stiffness", "layer_stiffness",
            "layer_distance",  "shape_matching",   "volume_stiffness",  "pressure",
            "damping",         "friction",         "collision_margin",  "linear_damping",
            "angular_damping", "restitution",      "hull_tolerance",    "position_iterations",
            "single_sheet"};
  return {};
}

namespace {
// Empty when `engine` is built in, else why not.
std::string unavailable(const std::string& engine) {
  const std::vector<std::string> have = available_engines();
  if (std::find(have.begin(), have.end(), engine) != have.end()) return {};
  std::string list;
  for (const auto& e : have) list += (list.empty() ? "" : ", ") + e;
  std::string msg = "engine '" + engine + "' is not built into this pbve (available: " +
                    (list.empty() ? std::string("none") : list);
  const std::string near = nearest_key(engine, have);
  if (!near.empty()) msg += "; did you mean '" + near + "'?";
  return msg + ")";
}
}  // namespace

std::unique_ptr<Simulator> make_engine(const EngineRecipe& r) {
#ifdef PBVE_ENGINE_MASS_SPRING
  if (r.simulation.engine == "mass_spring") return make_mass_spring(r);
#endif
#ifdef PBVE_ENGINE_BULLET
  if (r.simulation.engine == "bullet") return make_bullet(r);
#endif
  fail_key(r, "engine", 0, unavailable(r.simulation.engine));
}

void check_engine(const Scene& scene) {
  const std::string why = unavailable(scene.simulation.engine);
  if (!why.empty())
    throw InputError(why, scene.file, scene.line_of("simulation.engine"),
                     "key 'simulation.engine'");
  // The parameters too, which need no mesh: their errors come before any work (tracking).
  EngineRecipe r;
  r.simulation = scene.simulation;
  r.scene_file = scene.file;
  try {
#ifdef PBVE_ENGINE_MASS_SPRING
    if (scene.simulation.engine == "mass_spring") mass_spring_params(r);
#endif
#ifdef PBVE_ENGINE_BULLET
    if (scene.simulation.engine == "bullet") bullet_params(r);
#endif
  } catch (const InputError& e) {
    throw engine_error_in_scene(e, scene);
  }
}

}  // namespace pbve
