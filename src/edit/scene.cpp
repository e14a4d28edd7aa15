#include "pbve/edit/scene.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <sstream>
#include <tuple>
#include <utility>

#include <yaml-cpp/yaml.h>

#include "pbve/core/error.hpp"

namespace pbve {

namespace fs = std::filesystem;

std::string nearest_key(const std::string& key, const std::vector<std::string>& candidates) {
  // std::tolower takes the value of an unsigned char: a plain char above 0x7f is negative.
  const auto lower = [](char c) { return std::tolower(static_cast<unsigned char>(c)); };
  auto distance = [&](const std::string& a, const std::string& b) {
    std::vector<size_t> prev(b.size() + 1), cur(b.size() + 1);
    for (size_t j = 0; j <= b.size(); ++j) prev[j] = j;
    for (size_t i = 1; i <= a.size(); ++i) {
      cur[0] = i;
      for (size_t j = 1; j <= b.size(); ++j) {
        const size_t sub = prev[j - 1] + (lower(a[i - 1]) == lower(b[j - 1]) ? 0 : 1);
        cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, sub});
      }
      std::swap(prev, cur);
    }
    return prev[b.size()];
  };
  std::string best;
  size_t best_d = std::max<size_t>(2, key.size() / 2) + 1;
  for (const auto& c : candidates) {
    const size_t d = distance(key, c);
    if (d < best_d) {
      best_d = d;
      best = c;
    }
  }
  return best;
}

const std::vector<std::string> kSimulationKeys = {"engine", "material", "gravity", "ground",
                                                  "planes", "regions",  "substeps"};

namespace {

/// Reads typed values from YAML nodes, throwing InputError with file, line and key.
class Reader {
 public:
  Reader(fs::path file, std::map<std::string, int>& lines)
      : m_file(std::move(file)), m_lines(&lines) {}

  /// Records the line of `key` (dotted name) for later messages.
  void note(const std::string& key, const YAML::Node& key_node) const {
    (*m_lines)[key] = key_node.Mark().line + 1;
  }

  [[noreturn]] void fail(const YAML::Node& node, const std::string& key,
                         const std::string& message) const {
    // An empty value (`background:` with nothing after it) is a null node marked where the
    // parser found the next token, lines later: it is reported at its key's line.
    int line = node.IsDefined() ? node.Mark().line + 1 : 0;
    if (const auto it = m_lines->find(key); it != m_lines->end() && (line <= 0 || node.IsNull()))
      line = it->second;
    throw InputError(message, m_file, line > 0 ? line : 0, "key '" + key + "'");
  }

  /// Checks that `node` is a map whose keys are all in `allowed`.
  void check_map(const YAML::Node& node, const std::string& section,
                 const std::vector<std::string>& allowed) const {
    if (!node.IsMap()) fail(node, section, "expected a mapping of keys");
    for (const auto& kv : node) {
      const std::string k = kv.first.as<std::string>();
      if (std::find(allowed.begin(), allowed.end(), k) != allowed.end()) {
        note(join(section, k), kv.first);
        continue;
      }
      std::string msg = "unknown key";
      const std::string near = nearest_key(k, allowed);
      if (!near.empty()) msg += " (did you mean '" + near + "'?)";
      std::string valid;
      for (const auto& a : allowed) valid += (valid.empty() ? "" : ", ") + a;
      msg += "; valid keys here: " + valid;
      throw InputError(msg, m_file, kv.first.Mark().line + 1, "key '" + join(section, k) + "'");
    }
  }

  static std::string join(const std::string& section, const std::string& k) {
    return section.empty() ? k : section + "." + k;
  }

  double number(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar()) fail(n, key, "expected a number");
    double v = 0;
    const std::string s = n.Scalar();
    std::istringstream is(s);
    is >> v;
    if (is.fail() || !is.eof()) {
      // yaml-cpp accepts .inf / .nan spellings through as<double>.
      try {
        v = n.as<double>();
      } catch (const YAML::Exception&) {
        fail(n, key, "expected a number, found '" + s + "'");
      }
    }
    if (!std::isfinite(v)) fail(n, key, "expected a finite number, found '" + s + "'");
    return v;
  }
  double positive(const YAML::Node& n, const std::string& key) const {
    const double v = number(n, key);
    if (!(v > 0)) fail(n, key, "must be positive, found " + n.Scalar());
    return v;
  }
  int integer(const YAML::Node& n, const std::string& key) const {
    const double v = number(n, key);
    if (v != std::floor(v) || std::abs(v) > 2e9)
      fail(n, key, "expected an integer, found '" + n.Scalar() + "'");
    return static_cast<int>(v);
  }
  bool boolean(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar()) fail(n, key, "expected true or false");
    const std::string s = n.Scalar();
    if (s == "true" || s == "yes" || s == "on") return true;
    if (s == "false" || s == "no" || s == "off") return false;
    fail(n, key, "expected true or false, found '" + s + "'");
  }
  std::string string(const YAML::Node& n, const std::string& key) const {
    if (!n.IsScalar() || n.Scalar().empty()) fail(n, key, "expected a non-empty string");
    return n.Scalar();
  }
  std::string choice(const YAML::Node& n, const std::string& key,
                     const std::vector<std::string>& options) const {
    const std::string s = string(n, key);
    if (std::find(options.begin(), options.end(), s) != options.end()) return s;
    std::string msg = "'" + s + "' is not one of ";
    for (size_t i = 0; i < options.size(); ++i) msg += (i ? ", " : "") + options[i];
    const std::string near = nearest_key(s, options);
    if (!near.empty()) msg += " (did you mean '" + near + "'?)";
    fail(n, key, msg);
  }
  fs::path path(const YAML::Node& n, const std::string& key) const {
    const fs::path p = string(n, key);
    return p.is_absolute() ? p : (m_file.parent_path() / p).lexically_normal();
  }
  Eigen::Vector3d vec3(const YAML::Node& n, const std::string& key) const {
    if (!n.IsSequence() || n.size() != 3) fail(n, key, "expected a list of 3 numbers");
    return {number(n[0], key), number(n[1], key), number(n[2], key)};
  }
  ScenePlane plane(const YAML::Node& n, const std::string& key) const {
    check_map(n, key, {"point", "normal", "friction"});
    ScenePlane p;
    if (n["point"]) p.point = vec3(n["point"], key + ".point");
    if (n["normal"]) {
      p.normal = vec3(n["normal"], key + ".normal");
      if (!(p.normal.norm() > 1e-12)) fail(n["normal"], key + ".normal", "must not be zero");
      p.normal.normalize();
    }
    if (n["friction"]) {
      p.friction = number(n["friction"], key + ".friction");
      if (p.friction < 0) fail(n["friction"], key + ".friction", "must not be negative");
    }
    return p;
  }
  const fs::path& file() const { return m_file; }

 private:
  fs::path m_file;
  std::map<std::string, int>* m_lines;
};

void require(const Reader& r, const YAML::Node& parent, const char* name,
             const std::string& section) {
  if (!parent[name])
    throw InputError("missing required key", r.file(), parent.Mark().line + 1,
                     "key '" + Reader::join(section, name) + "'");
}

/// A `box: {min: [x,y,z], max: [x,y,z]}` under `key`: both corners required, min <= max.
std::pair<Eigen::Vector3d, Eigen::Vector3d> read_box(const Reader& r, const YAML::Node& b,
                                                     const std::string& key) {
  r.check_map(b, key, {"min", "max"});
  require(r, b, "min", key);
  require(r, b, "max", key);
  const Eigen::Vector3d lo = r.vec3(b["min"], key + ".min"), hi = r.vec3(b["max"], key + ".max");
  if ((lo.array() > hi.array()).any()) r.fail(b, key, "min must not exceed max in any coordinate");
  return {lo, hi};
}

}  // namespace

InputError engine_error_in_scene(const InputError& e, const Scene& scene) {
  if (e.file() != scene.file || e.line() > 0) return e;
  std::string message = e.message();
  const std::string prefix = scene.simulation.engine + ": ";
  while (message.rfind(prefix + prefix, 0) == 0) message.erase(0, prefix.size());
  std::string key;
  if (e.key().rfind("key '", 0) == 0 && e.key().size() > 6)
    key = e.key().substr(5, e.key().size() - 6);
  for (const auto& [name, value_line] : scene.simulation.parameters)
    if (key.empty() && message.find("parameter " + name + " ") != std::string::npos)
      key = "simulation." + name;
  if (key.empty()) return InputError(message, scene.file, 0, e.key());
  return InputError(message, scene.file, scene.line_of(key), "key '" + key + "'");
}

int Scene::line_of(const std::string& key) const {
  const auto it = lines.find(key);
  return it == lines.end() ? 0 : it->second;
}

namespace {

/// The scene key that sets a ControlOptions field, from the key of its InputError
/// ("ControlOptions::barrier.margin" -> "control.margin"); "control" for a field no key sets.
std::string scene_key_of_control_option(const std::string& option) {
  static const std::map<std::string, std::string> keys = {
      {"weights.visibility", "control.weights.visibility"},
      {"weights.force", "control.weights.force"},
      {"weights.temporal", "control.weights.temporal"},
      {"window", "control.window"},
      {"solver", "control.solver"},
      {"gradient", "control.gradient"},
      {"difference_rings", "control.difference_rings"},
      {"active_set", "control.active_set"},
      {"max_evaluations", "control.max_iterations"},
      {"initial_guess", "control.warm_start"},
      {"barrier.margin", "control.margin"},
      {"force_bound", "control.force_bound"},
      {"clusters", "control.clusters"},
      {"linearized", "control.linearized"},
      {"max_linearizations", "control.max_linearizations"},
      {"linearized_ftol_initial", "control.linearized_tolerance"},
  };
  const std::string prefix = "ControlOptions::";
  const std::string field =
      option.rfind(prefix, 0) == 0 ? option.substr(prefix.size()) : std::string();
  const auto it = keys.find(field);
  return it == keys.end() ? "control" : it->second;
}

}  // namespace

ControlOptions control_options(const Scene& scene) {
  const SceneControl& c = scene.control;
  ControlOptions o;
  o.weights.visibility = c.weight_visibility;
  o.weights.force = c.weight_force;
  o.weights.temporal = c.weight_temporal;
  o.window = c.window;
  try {
    o.solver = parse_control_solver(c.solver);
  } catch (const std::invalid_argument& e) {
    throw InputError(e.what(), scene.file, scene.line_of("control.solver"), "key 'control.solver'");
  }
  o.gradient = c.gradient == "central"      ? GradientMode::central
               : c.gradient == "compressed" ? GradientMode::compressed
               : c.gradient == "adjoint"    ? GradientMode::adjoint
                                            : GradientMode::automatic;
  o.difference_rings = c.difference_rings;
  o.active_set = c.active_set == "all" ? ActiveSet::all : ActiveSet::at_risk;
  o.max_evaluations = c.max_iterations;
  o.initial_guess = c.warm_start ? InitialGuess::previous : InitialGuess::zero;
  o.barrier.margin = c.margin;
  o.force_bound = c.force_bound;
  o.clusters = c.clusters;
  o.linearized = c.linearized;
  o.max_linearizations = c.max_linearizations;
  o.linearized_ftol_initial = c.linearized_tolerance;
  try {
    o.validate();
  } catch (const InputError& e) {
    const std::string key = scene_key_of_control_option(e.key());
    throw InputError(e.message(), scene.file, scene.line_of(key), "key '" + key + "'");
  }
  return o;
}

namespace {

/// Throws InputError at the second of two equal keys of any mapping under `node` (YAML
/// forbids them; the parser would keep the first silently). `prefix`: the dotted name of `node`.
void reject_duplicate_keys(const YAML::Node& node, const std::string& prefix,
                           const fs::path& path) {
  if (node.IsSequence()) {
    for (size_t i = 0; i < node.size(); ++i)
      reject_duplicate_keys(node[i], prefix + "[" + std::to_string(i) + "]", path);
    return;
  }
  if (!node.IsMap()) return;
  std::map<std::string, int> seen;
  for (const auto& kv : node) {
    const std::string key = kv.first.IsScalar() ? kv.first.Scalar() : std::string();
    const std::string name = prefix.empty() ? key : prefix + "." + key;
    const int line = kv.first.Mark().line + 1;
    if (kv.first.IsScalar()) {
      const auto [it, inserted] = seen.emplace(key, line);
      if (!inserted)
        throw InputError(
            "key given twice (first at line " + std::to_string(it->second) + "): remove one", path,
            line, "key '" + name + "'");
    }
    reject_duplicate_keys(kv.second, name, path);
  }
}

Scene parse_scene_nodes(const std::string& text, const fs::path& path) {
  Scene s;
  Reader r(path, s.lines);
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw InputError("YAML syntax error: " + e.msg, path, e.mark.line + 1);
  }
  if (!root.IsDefined() || root.IsNull()) throw InputError("the scene file is empty", path);
  reject_duplicate_keys(root, "", path);
  r.check_map(root, "",
              {"input", "camera", "object", "background", "simulation", "control", "output"});
  s.file = path;

  require(r, root, "input", "");
  {
    const YAML::Node n = root["input"];
    r.check_map(n, "input", {"video", "image", "sequence", "frames", "fps"});
    const int given = (n["video"] ? 1 : 0) + (n["image"] ? 1 : 0) + (n["sequence"] ? 1 : 0);
    if (given != 1) r.fail(n, "input", "give exactly one of video, image or sequence");
    if (n["video"]) s.input.video = r.path(n["video"], "input.video");
    if (n["image"]) {
      s.input.image = r.path(n["image"], "input.image");
      if (!n["frames"]) r.fail(n, "input.frames", "a single image needs a frame count");
    }
    if (n["sequence"]) {
      const std::string pat = r.string(n["sequence"], "input.sequence");
      const fs::path p = pat;
      s.input.sequence = (p.is_absolute() ? p : path.parent_path() / p).lexically_normal().string();
    }
    if (n["frames"]) {
      if (!n["image"]) r.fail(n["frames"], "input.frames", "only used with input.image");
      s.input.frames = r.integer(n["frames"], "input.frames");
      if (s.input.frames < 1) r.fail(n["frames"], "input.frames", "must be at least 1");
    }
    if (n["fps"]) {
      // A video's frame rate is its own (it was ignored without a word).
      if (n["video"])
        r.fail(n["fps"], "input.fps",
               "only used with input.image or input.sequence (a video has its own)");
      s.input.fps = r.positive(n["fps"], "input.fps");
      // (the video writer's codecs go to 1e6; 1e308 made it fail with codec noise)
      if (s.input.fps > 1e6)
        r.fail(n["fps"], "input.fps", "at most 1e6 frames per second, found " + n["fps"].Scalar());
    }
  }

  require(r, root, "camera", "");
  {
    const YAML::Node n = root["camera"];
    r.check_map(n, "camera", {"fx", "fy", "cx", "cy"});
    for (const char* k : {"fx", "fy", "cx", "cy"}) require(r, n, k, "camera");
    s.fx = r.positive(n["fx"], "camera.fx");
    s.fy = r.positive(n["fy"], "camera.fy");
    s.cx = r.number(n["cx"], "camera.cx");
    s.cy = r.number(n["cy"], "camera.cy");
  }

  require(r, root, "object", "");
  {
    const YAML::Node n = root["object"];
    r.check_map(n, "object",
                {"mesh", "poses", "initial_pose", "correspondences", "tracked_poses", "scale",
                 "refine", "fracture", "anchors"});
    require(r, n, "mesh", "object");
    require(r, n, "poses", "object");
    s.object.mesh = r.path(n["mesh"], "object.mesh");
    // `poses: track` runs the tracker first (a file named track: `./track`).
    s.object.track = n["poses"].IsScalar() && n["poses"].Scalar() == "track";
    if (!s.object.track) s.object.poses = r.path(n["poses"], "object.poses");
    for (const char* k : {"initial_pose", "correspondences", "tracked_poses"}) {
      if (!n[k]) continue;
      const std::string key = std::string("object.") + k;
      if (!s.object.track) r.fail(n[k], key, "only used with 'poses: track'");
      (k[0] == 'i'   ? s.object.initial_pose
       : k[0] == 'c' ? s.object.correspondences
                     : s.object.tracked_poses) = r.path(n[k], key);
    }
    if (s.object.track && !n["initial_pose"] == !n["correspondences"])
      r.fail(n["poses"], "object.poses",
             "'poses: track' needs the pose in the first frame: give exactly one of "
             "object.initial_pose (a pose file) or object.correspondences (at least 4 "
             "'VERTEX u v' or 'x y z u v' lines)");
    if (n["scale"]) {
      s.object.scale = r.positive(n["scale"], "object.scale");
      // A small enlargement over the silhouette, not a change of units (1000 blew the mesh
      // over the whole frame and blacked the background out without a word).
      if (s.object.scale < 0.9 || s.object.scale > 1.5)
        r.fail(n["scale"], "object.scale",
               "the mesh's small enlargement over the object's silhouette (paper: 1.01) must "
               "be between 0.9 and 1.5, found " +
                   n["scale"].Scalar() + " (convert a mesh in other units before)");
    }
    if (n["refine"]) s.object.refine = r.positive(n["refine"], "object.refine");
    if (n["fracture"]) {
      const YAML::Node f = n["fracture"];
      r.check_map(f, "object.fracture", {"pieces", "seed"});
      require(r, f, "pieces", "object.fracture");
      s.object.fracture_pieces = r.integer(f["pieces"], "object.fracture.pieces");
      if (s.object.fracture_pieces < 2 || s.object.fracture_pieces > 1000)
        r.fail(f["pieces"], "object.fracture.pieces",
               "must be between 2 and 1000, found " + f["pieces"].Scalar());
      if (f["seed"]) {
        s.object.fracture_seed = r.integer(f["seed"], "object.fracture.seed");
        if (s.object.fracture_seed < 0)
          r.fail(f["seed"], "object.fracture.seed", "must not be negative");
      }
    }
    if (n["anchors"]) {
      const YAML::Node a = n["anchors"];
      r.check_map(a, "object.anchors", {"vertices", "box"});
      if (a["vertices"]) {
        if (!a["vertices"].IsSequence())
          r.fail(a["vertices"], "object.anchors.vertices", "expected a list of vertex indices");
        for (const auto& v : a["vertices"]) {
          const int id = r.integer(v, "object.anchors.vertices");
          if (id < 0) r.fail(v, "object.anchors.vertices", "vertex index must not be negative");
          s.object.anchors.vertices.push_back(id);
        }
      }
      if (a["box"]) {
        const auto [lo, hi] = read_box(r, a["box"], "object.anchors.box");
        s.object.anchors.box_min = lo;
        s.object.anchors.box_max = hi;
      }
    }
  }

  if (root["background"]) {
    const YAML::Node n = root["background"];
    r.check_map(n, "background", {"plate", "remove"});
    if (n["plate"]) s.background.plate = r.path(n["plate"], "background.plate");
    if (n["remove"]) {
      const fs::path p = r.string(n["remove"], "background.remove");
      s.background.remove =
          (p.is_absolute() ? p : path.parent_path() / p).lexically_normal().string();
    }
  }

  if (root["simulation"]) {
    const YAML::Node n = root["simulation"];
    if (!n.IsMap()) r.fail(n, "simulation", "expected a mapping of keys");
    for (const auto& kv : n) {
      const std::string k = kv.first.as<std::string>();
      const std::string key = "simulation." + k;
      const YAML::Node& v = kv.second;
      r.note(key, kv.first);
      if (k == "engine") {
        // Any engine name: the built-in ones (pbve::make_engine() checks which this build
        // has) or an adapter of the program's own, which its factory selects by this name.
        const std::string name = r.string(v, key);
        const bool identifier =
            std::isalpha(static_cast<unsigned char>(name[0])) != 0 &&
            std::all_of(name.begin(), name.end(), [](char ch) {
              return std::isalnum(static_cast<unsigned char>(ch)) != 0 || ch == '_';
            });
        if (!identifier)
          r.fail(v, key,
                 "expected an engine name (a letter, then letters, digits or '_'), found '" + name +
                     "'");
        s.simulation.engine = name;
      } else if (k == "material") {
        s.simulation.material = r.choice(v, key, {"cloth", "elastic", "stiff", "rigid"});
      } else if (k == "gravity") {
        s.simulation.gravity = r.vec3(v, key);
      } else if (k == "ground") {
        s.simulation.ground = r.plane(v, key);
      } else if (k == "planes") {
        if (!v.IsSequence()) r.fail(v, key, "expected a list of planes");
        for (const auto& p : v) s.simulation.planes.push_back(r.plane(p, key));
      } else if (k == "regions") {
        if (!v.IsSequence()) r.fail(v, key, "expected a list of regions");
        for (const auto& e : v) {
          if (!e.IsMap())
            r.fail(e, key, "expected {box: {min: [x,y,z], max: [x,y,z]}, PARAMETER: VALUE}");
          SceneRegion region;
          region.line = e.Mark().line + 1;
          require(r, e, "box", key);
          for (const auto& rkv : e) {
            const std::string rk = rkv.first.as<std::string>();
            if (rk == "box") {
              std::tie(region.box_min, region.box_max) = read_box(r, rkv.second, key + ".box");
            } else if (rkv.second.IsScalar()) {
              region.parameters[rk] = {r.number(rkv.second, key + "." + rk),
                                       rkv.second.Mark().line + 1};
            } else {
              r.fail(rkv.second, key + "." + rk, "expected a number (a material parameter)");
            }
          }
          if (region.parameters.empty())
            r.fail(e, key, "a region needs a material parameter besides its box");
          s.simulation.regions.push_back(std::move(region));
        }
      } else if (k == "substeps") {
        s.simulation.substeps = r.integer(v, key);
        if (s.simulation.substeps < 1 || s.simulation.substeps > 10000)
          r.fail(v, key, "must be between 1 and 10000");
      } else {
        // A material parameter (a number; its name and range are checked by the engine), or
        // a misspelt key of this section (`materal: elastic`, `grond: {...}`).
        const std::string near = nearest_key(k, kSimulationKeys);
        const InputError misspelt("unknown key (did you mean '" + near + "'?)", path,
                                  kv.first.Mark().line + 1, "key '" + key + "'");
        if (!v.IsScalar()) {
          if (!near.empty()) throw misspelt;
          r.fail(v, key, "expected a number (a material parameter)");
        }
        try {
          s.simulation.parameters[k] = {r.number(v, key), v.Mark().line + 1};
        } catch (const InputError&) {
          if (!near.empty()) throw misspelt;
          throw;
        }
      }
    }
  }

  if (root["control"]) {
    const YAML::Node n = root["control"];
    r.check_map(n, "control",
                {"enabled", "weights", "window", "solver", "gradient", "active_set",
                 "max_iterations", "warm_start", "margin", "force_bound", "clusters", "linearized",
                 "max_linearizations", "linearized_tolerance", "difference_rings"});
    SceneControl& c = s.control;
    for (const auto& kv : n) c.given[kv.first.as<std::string>()] = kv.first.Mark().line + 1;
    if (n["enabled"]) c.enabled = r.boolean(n["enabled"], "control.enabled");
    if (n["weights"]) {
      const YAML::Node w = n["weights"];
      r.check_map(w, "control.weights", {"visibility", "force", "temporal"});
      auto weight = [&](const char* k, double& out) {
        if (!w[k]) return;
        out = r.number(w[k], std::string("control.weights.") + k);
        if (out < 0) r.fail(w[k], std::string("control.weights.") + k, "must not be negative");
      };
      weight("visibility", c.weight_visibility);
      weight("force", c.weight_force);
      weight("temporal", c.weight_temporal);
    }
    if (n["window"]) {
      c.window = r.integer(n["window"], "control.window");
      if (c.window < 1 || c.window > 100)
        r.fail(n["window"], "control.window", "must be between 1 and 100");
    }
    if (n["solver"])
      c.solver =
          r.choice(n["solver"], "control.solver", {"slsqp", "mma", "lbfgs", "cobyla", "ipopt"});
    if (n["gradient"])
      c.gradient =
          r.choice(n["gradient"], "control.gradient", {"auto", "central", "compressed", "adjoint"});
    if (n["active_set"])
      c.active_set = r.choice(n["active_set"], "control.active_set", {"auto", "all"});
    if (n["max_iterations"]) {
      c.max_iterations = r.integer(n["max_iterations"], "control.max_iterations");
      if (c.max_iterations < 1)
        r.fail(n["max_iterations"], "control.max_iterations", "must be at least 1");
    }
    if (n["warm_start"]) c.warm_start = r.boolean(n["warm_start"], "control.warm_start");
    // The range of margin (and the other values' as the optimizer sees them): control_options().
    if (n["margin"]) c.margin = r.number(n["margin"], "control.margin");
    if (n["clusters"]) {
      c.clusters = r.integer(n["clusters"], "control.clusters");
      if (c.clusters < 0) r.fail(n["clusters"], "control.clusters", "must not be negative");
    }
    if (n["difference_rings"]) {
      c.difference_rings = r.integer(n["difference_rings"], "control.difference_rings");
      if (c.difference_rings < 0 || c.difference_rings > 50)
        r.fail(n["difference_rings"], "control.difference_rings", "must be between 0 and 50");
    }
    if (n["linearized"]) c.linearized = r.boolean(n["linearized"], "control.linearized");
    if (n["max_linearizations"]) {
      c.max_linearizations = r.integer(n["max_linearizations"], "control.max_linearizations");
      if (c.max_linearizations < 1)
        r.fail(n["max_linearizations"], "control.max_linearizations", "must be at least 1");
    }
    if (n["linearized_tolerance"]) {
      c.linearized_tolerance = r.number(n["linearized_tolerance"], "control.linearized_tolerance");
      if (!(c.linearized_tolerance >= 0.0 && c.linearized_tolerance < 1.0))
        r.fail(n["linearized_tolerance"], "control.linearized_tolerance",
               "must be at least 0 and less than 1");
    }
    if (n["force_bound"]) {
      c.force_bound = r.number(n["force_bound"], "control.force_bound");
      if (c.force_bound < 0)
        r.fail(n["force_bound"], "control.force_bound", "must not be negative");
    }
  }

  control_options(s);  // the optimizer's own checks, at the key that set the field

  require(r, root, "output", "");
  {
    const YAML::Node n = root["output"];
    r.check_map(n, "output", {"video", "report"});
    require(r, n, "video", "output");
    s.output.video = r.path(n["video"], "output.video");
    if (n["report"]) s.output.report = r.path(n["report"], "output.report");
  }
  return s;
}

}  // namespace

Scene parse_scene(const std::string& text, const fs::path& path) {
  try {
    return parse_scene_nodes(text, path);
  } catch (const YAML::Exception& e) {
    // E.g. a key that is itself a list or mapping: yaml-cpp cannot convert it to a string.
    throw InputError("unexpected YAML structure: " + e.msg, path,
                     e.mark.is_null() ? 0 : e.mark.line + 1);
  }
}

Scene load_scene(const fs::path& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw InputError("scene file not found", path);
  if (fs::is_directory(path, ec)) throw InputError("the scene file is a folder", path);
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("cannot open the scene file", path);
  std::stringstream ss;
  ss << in.rdbuf();
  return parse_scene(ss.str(), fs::absolute(path));
}

std::string scene_to_yaml(const Scene& s) {
  YAML::Emitter e;
  auto vec = [&](const Eigen::Vector3d& v) {
    e << YAML::Flow << YAML::BeginSeq << v.x() << v.y() << v.z() << YAML::EndSeq;
  };
  auto plane = [&](const ScenePlane& p) {
    e << YAML::BeginMap << YAML::Key << "point" << YAML::Value;
    vec(p.point);
    e << YAML::Key << "normal" << YAML::Value;
    vec(p.normal);
    e << YAML::Key << "friction" << YAML::Value << p.friction << YAML::EndMap;
  };
  e << YAML::BeginMap;
  e << YAML::Key << "input" << YAML::Value << YAML::BeginMap;
  if (!s.input.video.empty()) e << YAML::Key << "video" << YAML::Value << s.input.video.string();
  if (!s.input.image.empty()) {
    e << YAML::Key << "image" << YAML::Value << s.input.image.string();
    e << YAML::Key << "frames" << YAML::Value << s.input.frames;
  }
  if (!s.input.sequence.empty()) e << YAML::Key << "sequence" << YAML::Value << s.input.sequence;
  if (s.input.video.empty()) e << YAML::Key << "fps" << YAML::Value << s.input.fps;
  e << YAML::EndMap;
  e << YAML::Key << "camera" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key << "fx"
    << YAML::Value << s.fx << YAML::Key << "fy" << YAML::Value << s.fy << YAML::Key << "cx"
    << YAML::Value << s.cx << YAML::Key << "cy" << YAML::Value << s.cy << YAML::EndMap;
  e << YAML::Key << "object" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "mesh" << YAML::Value << s.object.mesh.string();
  if (s.object.track) {
    e << YAML::Key << "poses" << YAML::Value << "track";
    if (!s.object.initial_pose.empty())
      e << YAML::Key << "initial_pose" << YAML::Value << s.object.initial_pose.string();
    if (!s.object.correspondences.empty())
      e << YAML::Key << "correspondences" << YAML::Value << s.object.correspondences.string();
    e << YAML::Key << "tracked_poses" << YAML::Value
      << (s.object.tracked_poses.empty() ? std::string("automatic")
                                         : s.object.tracked_poses.string());
  } else {
    e << YAML::Key << "poses" << YAML::Value << s.object.poses.string();
  }
  e << YAML::Key << "scale" << YAML::Value << s.object.scale;
  if (s.object.refine > 0) e << YAML::Key << "refine" << YAML::Value << s.object.refine;
  if (s.object.fracture_pieces > 0)
    e << YAML::Key << "fracture" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
      << "pieces" << YAML::Value << s.object.fracture_pieces << YAML::Key << "seed" << YAML::Value
      << s.object.fracture_seed << YAML::EndMap;
  e << YAML::Key << "anchors" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "vertices" << YAML::Value << YAML::Flow << s.object.anchors.vertices;
  if (s.object.anchors.box_min) {
    e << YAML::Key << "box" << YAML::Value << YAML::BeginMap << YAML::Key << "min" << YAML::Value;
    vec(*s.object.anchors.box_min);
    e << YAML::Key << "max" << YAML::Value;
    vec(*s.object.anchors.box_max);
    e << YAML::EndMap;
  }
  e << YAML::EndMap << YAML::EndMap;
  e << YAML::Key << "background" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "plate" << YAML::Value
    << (s.background.plate.empty() ? std::string("automatic") : s.background.plate.string());
  if (!s.background.remove.empty())
    e << YAML::Key << "remove" << YAML::Value << s.background.remove;
  e << YAML::EndMap;
  e << YAML::Key << "simulation" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "engine" << YAML::Value << s.simulation.engine;
  e << YAML::Key << "material" << YAML::Value << s.simulation.material;
  e << YAML::Key << "gravity" << YAML::Value;
  vec(s.simulation.gravity);
  if (s.simulation.ground) {
    e << YAML::Key << "ground" << YAML::Value;
    plane(*s.simulation.ground);
  }
  if (!s.simulation.planes.empty()) {
    e << YAML::Key << "planes" << YAML::Value << YAML::BeginSeq;
    for (const auto& p : s.simulation.planes) plane(p);
    e << YAML::EndSeq;
  }
  e << YAML::Key << "substeps" << YAML::Value << s.simulation.substeps;
  if (!s.simulation.regions.empty()) {
    e << YAML::Key << "regions" << YAML::Value << YAML::BeginSeq;
    for (const SceneRegion& g : s.simulation.regions) {
      e << YAML::BeginMap << YAML::Key << "box" << YAML::Value << YAML::BeginMap << YAML::Key
        << "min" << YAML::Value;
      vec(g.box_min);
      e << YAML::Key << "max" << YAML::Value;
      vec(g.box_max);
      e << YAML::EndMap;
      for (const auto& [k, v] : g.parameters) e << YAML::Key << k << YAML::Value << v.first;
      e << YAML::EndMap;
    }
    e << YAML::EndSeq;
  }
  for (const auto& [k, v] : s.simulation.parameters) e << YAML::Key << k << YAML::Value << v.first;
  e << YAML::EndMap;
  const SceneControl& c = s.control;
  e << YAML::Key << "control" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "enabled" << YAML::Value << c.enabled;
  e << YAML::Key << "weights" << YAML::Value << YAML::Flow << YAML::BeginMap << YAML::Key
    << "visibility" << YAML::Value << c.weight_visibility << YAML::Key << "force" << YAML::Value
    << c.weight_force << YAML::Key << "temporal" << YAML::Value << c.weight_temporal
    << YAML::EndMap;
  e << YAML::Key << "window" << YAML::Value << c.window;
  e << YAML::Key << "solver" << YAML::Value << c.solver;
  e << YAML::Key << "gradient" << YAML::Value << c.gradient;
  e << YAML::Key << "active_set" << YAML::Value << c.active_set;
  e << YAML::Key << "max_iterations" << YAML::Value << c.max_iterations;
  e << YAML::Key << "warm_start" << YAML::Value << c.warm_start;
  e << YAML::Key << "margin" << YAML::Value << c.margin;
  e << YAML::Key << "force_bound" << YAML::Value << c.force_bound;
  e << YAML::Key << "clusters" << YAML::Value << c.clusters;
  e << YAML::Key << "difference_rings" << YAML::Value << c.difference_rings;
  e << YAML::Key << "linearized" << YAML::Value << c.linearized;
  e << YAML::Key << "max_linearizations" << YAML::Value << c.max_linearizations;
  e << YAML::Key << "linearized_tolerance" << YAML::Value << c.linearized_tolerance;
  e << YAML::EndMap;
  e << YAML::Key << "output" << YAML::Value << YAML::BeginMap;
  e << YAML::Key << "video" << YAML::Value << s.output.video.string();
  if (!s.output.report.empty())
    e << YAML::Key << "report" << YAML::Value << s.output.report.string();
  e << YAML::EndMap << YAML::EndMap;
  return e.c_str();
}

}  // namespace pbve
