#include <cmath>
#include <stdexcept>
#include <string>

#include "pbve/mass_spring/mass_spring.hpp"

namespace pbve::mass_spring {

namespace {

[[noreturn]] void bad(const std::string& name, const std::string& what, double value) {
  throw std::invalid_argument("mass_spring: parameter " + name + " must be " + what + " (got " +
                              std::to_string(value) + ")");
}
void positive(double value, const char* name) {
  if (!(value > 0.0) || !std::isfinite(value)) bad(name, "positive and finite", value);
}
void non_negative(double value, const char* name) {
  if (!(value >= 0.0) || !std::isfinite(value)) bad(name, "non-negative and finite", value);
}

}  // namespace

Material material_from_string(const std::string& name) {
  if (name == "cloth") return Material::cloth;
  if (name == "elastic") return Material::elastic;
  if (name == "stiff") return Material::stiff;
  throw std::invalid_argument("mass_spring: unknown material '" + name +
                              "' (expected cloth, elastic or stiff)");
}

std::string to_string(Material m) {
  switch (m) {
    case Material::cloth:
      return "cloth";
    case Material::elastic:
      return "elastic";
    case Material::stiff:
      return "stiff";
  }
  return "unknown";
}

Params Params::preset(Material m) {
  Params p;
  p.material = m;
  switch (m) {
    case Material::cloth:
      break;  // the field defaults are the cloth preset
    case Material::elastic:
      p.density = 1000.0;
      p.stretch_stiffness = 200.0;
      p.shear_stiffness = 20.0;
      p.bend_stiffness = 1e-4;
      p.volume_stiffness = 2e4;
      p.damping_alpha = 0.5;
      p.damping_beta = 0.002;
      break;
    case Material::stiff:
      p.density = 1000.0;
      p.stretch_stiffness = 2e5;
      p.shear_stiffness = 2e4;
      p.bend_stiffness = 1e-2;
      p.volume_stiffness = 2e7;
      p.damping_alpha = 0.5;
      p.damping_beta = 2e-4;
      break;
  }
  return p;
}

void Params::validate() const {
  positive(density, "density");
  positive(stretch_stiffness, "stretch_stiffness");
  non_negative(shear_stiffness, "shear_stiffness");
  non_negative(bend_stiffness, "bend_stiffness");
  non_negative(layer_stiffness, "layer_stiffness");
  non_negative(layer_distance, "layer_distance");
  if (single_sheet != 0 && single_sheet != 1) bad("single_sheet", "0 or 1", single_sheet);
  if (material != Material::cloth) positive(volume_stiffness, "volume_stiffness");
  non_negative(lattice_spacing, "lattice_spacing");
  if (!regions.empty() && material == Material::cloth)
    throw std::invalid_argument(
        "mass_spring: parameter regions applies to solids (elastic, stiff), not to cloth");
  for (size_t i = 0; i < regions.size(); ++i) {
    const StiffnessRegion& r = regions[i];
    const std::string name = "regions[" + std::to_string(i) + "]";
    if (!r.min.allFinite() || !r.max.allFinite() || (r.min.array() > r.max.array()).any())
      throw std::invalid_argument("mass_spring: parameter " + name +
                                  " needs finite corners with min <= max in every coordinate");
    positive(r.volume_stiffness, (name + ".volume_stiffness").c_str());
  }
  non_negative(damping_alpha, "damping_alpha");
  non_negative(damping_beta, "damping_beta");
  if (!gravity.allFinite())
    throw std::invalid_argument("mass_spring: parameter gravity must be finite");
  if (substeps < 1) bad("substeps", "at least 1", substeps);
  if (newton_iterations < 1) bad("newton_iterations", "at least 1", newton_iterations);
  positive(newton_tolerance, "newton_tolerance");
  positive(adjoint_tolerance, "adjoint_tolerance");
  if (direct_solver_max_dofs < 0)
    bad("direct_solver_max_dofs", "non-negative", direct_solver_max_dofs);
  if (direct_solver_max_dofs_layered < 0)
    bad("direct_solver_max_dofs_layered", "non-negative", direct_solver_max_dofs_layered);
  positive(friction_velocity, "friction_velocity");
  if (!planes.empty()) positive(contact_stiffness, "contact_stiffness");
  for (size_t i = 0; i < planes.size(); ++i) {
    const Plane& pl = planes[i];
    if (!pl.point.allFinite() || !pl.normal.allFinite() || !(pl.normal.norm() > 0.0))
      throw std::invalid_argument("mass_spring: parameter planes[" + std::to_string(i) +
                                  "] needs a finite point and a non-zero normal");
    if (!(pl.friction >= 0.0) || !std::isfinite(pl.friction))
      bad("planes[" + std::to_string(i) + "].friction", "non-negative and finite", pl.friction);
  }
}

}  // namespace pbve::mass_spring
