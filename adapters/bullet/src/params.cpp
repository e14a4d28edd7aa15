#include <cmath>
#include <stdexcept>
#include <string>

#include "pbve/bullet/bullet.hpp"

namespace pbve::bullet {

namespace {

[[noreturn]] void bad(const std::string& name, const std::string& what, double value) {
  throw std::invalid_argument("bullet: parameter " + name + " must be " + what + " (got " +
                              std::to_string(value) + ")");
}
void positive(double value, const char* name) {
  if (!(value > 0.0) || !std::isfinite(value)) bad(name, "positive and finite", value);
}
void non_negative(double value, const char* name) {
  if (!(value >= 0.0) || !std::isfinite(value)) bad(name, "non-negative and finite", value);
}
void fraction(double value, const char* name, bool allow_zero, bool allow_one) {
  const bool ok =
      (allow_zero ? value >= 0.0 : value > 0.0) && (allow_one ? value <= 1.0 : value < 1.0);
  if (!ok)
    bad(name, std::string("in ") + (allow_zero ? "[0" : "(0") + ", 1" + (allow_one ? "]" : ")"),
        value);
}

}  // namespace

Material material_from_string(const std::string& name) {
  if (name == "cloth") return Material::cloth;
  if (name == "elastic") return Material::elastic;
  if (name == "stiff") return Material::stiff;
  if (name == "rigid") return Material::rigid;
  throw std::invalid_argument("bullet: unknown material '" + name +
                              "' (expected cloth, elastic, stiff or rigid)");
}

std::string to_string(Material m) {
  switch (m) {
    case Material::cloth:
      return "cloth";
    case Material::elastic:
      return "elastic";
    case Material::stiff:
      return "stiff";
    case Material::rigid:
      return "rigid";
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
      p.linear_stiffness = 0.2;
      p.bending_stiffness = 0.1;
      p.volume_stiffness = 2e4;
      p.shape_matching = 0.01;
      p.damping = 0.02;
      break;
    case Material::stiff:
      p.density = 1000.0;
      p.linear_stiffness = 1.0;
      p.bending_stiffness = 1.0;
      p.volume_stiffness = 2e6;
      p.shape_matching = 0.5;
      p.damping = 0.02;
      p.position_iterations = 8;
      break;
    case Material::rigid:
      p.density = 1000.0;
      p.bending_stiffness = 0.0;
      p.damping = 0.0;
      p.collision_margin = 0.001;
      break;
  }
  return p;
}

void Params::validate() const {
  positive(density, "density");
  fraction(linear_stiffness, "linear_stiffness", false, true);
  fraction(bending_stiffness, "bending_stiffness", true, true);
  if (single_sheet != 0 && single_sheet != 1) bad("single_sheet", "0 or 1", single_sheet);
  fraction(layer_stiffness, "layer_stiffness", true, true);
  non_negative(layer_distance, "layer_distance");
  fraction(shape_matching, "shape_matching", true, true);
  // Shape matching pulls a solid towards its rest shape; a cloth has none to keep (a value was
  // silently dropped before).
  if (material == Material::cloth && shape_matching != 0.0)
    bad("shape_matching", "0 for cloth (it applies to elastic and stiff solids)", shape_matching);
  non_negative(volume_stiffness, "volume_stiffness");
  non_negative(pressure, "pressure");
  fraction(damping, "damping", true, false);
  non_negative(friction, "friction");
  if (position_iterations < 1) bad("position_iterations", "at least 1", position_iterations);
  positive(collision_margin, "collision_margin");
  fraction(linear_damping, "linear_damping", true, true);
  fraction(angular_damping, "angular_damping", true, true);
  fraction(restitution, "restitution", true, true);
  non_negative(hull_tolerance, "hull_tolerance");
  if (!gravity.allFinite()) throw std::invalid_argument("bullet: parameter gravity must be finite");
  if (substeps < 1) bad("substeps", "at least 1", substeps);
  for (size_t i = 0; i < planes.size(); ++i) {
    const Plane& pl = planes[i];
    if (!pl.point.allFinite() || !pl.normal.allFinite() || !(pl.normal.norm() > 0.0))
      throw std::invalid_argument("bullet: parameter planes[" + std::to_string(i) +
                                  "] needs a finite point and a non-zero normal");
    if (!(pl.friction >= 0.0) || !std::isfinite(pl.friction))
      bad("planes[" + std::to_string(i) + "].friction", "non-negative and finite", pl.friction);
  }
}

}  // namespace pbve::bullet
