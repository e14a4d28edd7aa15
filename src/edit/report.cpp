#include "pbve/edit/report.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <fstream>
#include <limits>
#include <sstream>

#include <yaml-cpp/yaml.h>
#include <nlohmann/json.hpp>

#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"

namespace pbve {

namespace {

using nlohmann::json;

json yaml_to_json(const YAML::Node& n) {
  switch (n.Type()) {
    case YAML::NodeType::Map: {
      json j = json::object();
      for (const auto& kv : n) j[kv.first.as<std::string>()] = yaml_to_json(kv.second);
      return j;
    }
    case YAML::NodeType::Sequence: {
      json j = json::array();
      for (const auto& v : n) j.push_back(yaml_to_json(v));
      return j;
    }
    case YAML::NodeType::Scalar: {
      const std::string s = n.Scalar();
      if (s == "true") return true;
      if (s == "false") return false;
      char* end = nullptr;
      errno = 0;
      const long long i = std::strtoll(s.c_str(), &end, 10);  // integers stay integers
      if (!s.empty() && end == s.c_str() + s.size() && errno != ERANGE) return i;
      const double d = std::strtod(s.c_str(), &end);
      if (!s.empty() && end == s.c_str() + s.size()) return d;
      return s;
    }
    default:
      return nullptr;
  }
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

ReportSummary Report::summary() const {
  ReportSummary s;
  s.frames = static_cast<int>(frames.size());
  if (frames.empty()) return s;
  // Sums and counts over the figures that are numbers: NaN is unknown, not a value (and would
  // break the ordering the median sorts by).
  struct Mean {
    double sum = 0.0;
    int count = 0;
    void add(double v) {
      if (std::isnan(v)) return;
      sum += v;
      ++count;
    }
    double value() const {
      return count > 0 ? sum / count : std::numeric_limits<double>::quiet_NaN();
    }
  };
  Mean violation, frame_ms, solve_ms;
  double violation_max = -std::numeric_limits<double>::infinity();
  std::vector<double> ratios;
  for (const FrameRecord& f : frames) {
    violation.add(f.violation_pct);
    if (!std::isnan(f.violation_pct)) violation_max = std::max(violation_max, f.violation_pct);
    frame_ms.add(f.frame_ms);
    solve_ms.add(f.solve_ms);
    if (f.physical_force > 0.0) {
      const double ratio = f.control_force / f.physical_force;
      if (!std::isnan(ratio)) ratios.push_back(ratio);
    }
    for (const double v :
         {f.violation_pct, f.control_force, f.physical_force, f.frame_ms, f.solve_ms})
      if (std::isnan(v)) {
        ++s.nan_frames;
        break;
      }
  }
  s.violation_pct_mean = violation.value();
  s.violation_pct_max =
      violation.count > 0 ? violation_max : std::numeric_limits<double>::quiet_NaN();
  s.ms_per_frame_mean = frame_ms.value();
  s.solve_ms_mean = solve_ms.value();
  s.control_to_physical_force_median = median(std::move(ratios));
  return s;
}

std::vector<std::string> faithfulness_warnings(const std::vector<FrameRecord>& frames,
                                               double ratio) {
  std::vector<std::string> out;
  const int pct = static_cast<int>(std::lround(100.0 * ratio));
  size_t i = 0;
  while (i < frames.size()) {
    auto over = [&](const FrameRecord& f) {
      return f.physical_force > 0.0 && f.control_force > ratio * f.physical_force;
    };
    if (!over(frames[i])) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j + 1 < frames.size() && over(frames[j + 1])) ++j;
    std::ostringstream msg;
    msg << "control forces exceed " << pct << "% of physical forces in frame";
    if (i == j)
      msg << ' ' << frames[i].index;
    else
      msg << "s " << frames[i].index << '-' << frames[j].index;
    msg << ": the requested physics is not faithfully reproduced";
    out.push_back(msg.str());
    i = j + 1;
  }
  return out;
}

void write_report(const Report& report, const std::filesystem::path& path) {
  json j;
  j["complete"] = report.complete;
  if (!report.complete) {
    j["stopped_at"] = report.stopped_at;
    j["stopped_reason"] = report.stopped_reason;
  }
  j["engine"] = report.engine;
  json frames = json::array();
  for (const FrameRecord& f : report.frames) {
    frames.push_back({{"index", f.index},
                      {"violation_pct", f.violation_pct},
                      {"visible_area_px", f.visible_area_px},
                      {"control_force", f.control_force},
                      {"physical_force", f.physical_force},
                      {"solve_ms", f.solve_ms},
                      {"frame_ms", f.frame_ms},
                      {"iterations", f.iterations},
                      {"status", f.status},
                      {"pose_lost", f.pose_lost},
                      {"substep_factor", f.substep_factor}});
  }
  j["frames"] = std::move(frames);
  if (report.tracking)
    j["tracking"] = {{"poses", report.tracking->poses.string()},
                     {"lost_frames", report.tracking->lost},
                     {"lost", report.tracking->lost.size()},
                     {"ms_per_frame", report.tracking->ms_per_frame},
                     {"left_view_at", report.tracking->left_view_at}};
  const ReportSummary s = report.summary();
  j["summary"] = {{"frames", s.frames},
                  {"violation_pct_mean", s.violation_pct_mean},
                  {"violation_pct_max", s.violation_pct_max},
                  {"control_to_physical_force_median", s.control_to_physical_force_median},
                  {"ms_per_frame_mean", s.ms_per_frame_mean},
                  {"solve_ms_mean", s.solve_ms_mean},
                  {"nan_frames", s.nan_frames},
                  {"warnings", report.warnings}};
  j["settings"] = json::object();
  if (!report.settings_yaml.empty()) {
    try {
      j["settings"] = yaml_to_json(YAML::Load(report.settings_yaml));
    } catch (const YAML::Exception&) {
      j["settings"] = report.settings_yaml;  // not YAML (set in code): kept as text
    }
  }
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw InputError("cannot write the report", path);
    // JSON text is UTF-8: a byte of a string that is not (a Latin-1 file name, say) is written
    // as U+FFFD, the replacement character; nlohmann::json has no lossless escape for it.
    out << j.dump(2, ' ', false, json::error_handler_t::replace) << '\n';
    if (!out) throw InputError("failed while writing the report", path);
  });
}

namespace {

/// Reads typed fields of a report, throwing InputError that names the file and the field
/// (`frames[3].violation_pct`): JSON has no lines worth quoting once parsed.
class ReportFields {
 public:
  explicit ReportFields(const std::filesystem::path& path) : m_path(path) {}

  [[noreturn]] void fail(const std::string& key, const std::string& message) const {
    throw InputError("not a pbve report: " + message, m_path, 0,
                     key.empty() ? std::string() : "key '" + key + "'");
  }
  static const char* kind(const json& v) {
    if (v.is_boolean()) return "true or false";
    if (v.is_number()) return "a number";
    if (v.is_string()) return "a string";
    if (v.is_array()) return "a list";
    if (v.is_object()) return "an object";
    return "null";
  }
  /// `o[name]`, or nullptr when absent (fail() when `required`).
  const json* field(const json& o, const std::string& where, const char* name,
                    bool required) const {
    const auto it = o.find(name);
    if (it != o.end()) return &*it;
    if (required) fail(where + name, "missing");
    return nullptr;
  }
  double number(const json& o, const std::string& where, const char* name, bool required,
                double fallback) const {
    const json* v = field(o, where, name, required);
    if (!v) return fallback;
    // JSON has no NaN or infinity: write_report() writes a figure that is not finite as null.
    if (v->is_null()) return std::numeric_limits<double>::quiet_NaN();
    if (!v->is_number()) fail(where + name, std::string("expected a number, found ") + kind(*v));
    return v->get<double>();
  }
  int integer(const json& o, const std::string& where, const char* name, bool required,
              int fallback) const {
    const json* v = field(o, where, name, required);
    if (!v) return fallback;
    if (!v->is_number())
      fail(where + name, std::string("expected a whole number, found ") + kind(*v));
    const double d = v->get<double>();
    if (d != std::floor(d) || std::abs(d) > 2e9)
      fail(where + name, "expected a whole number, found " + v->dump());
    return static_cast<int>(d);
  }
  bool boolean(const json& o, const std::string& where, const char* name, bool fallback) const {
    const json* v = field(o, where, name, false);
    if (!v) return fallback;
    if (!v->is_boolean())
      fail(where + name, std::string("expected true or false, found ") + kind(*v));
    return v->get<bool>();
  }
  std::string string(const json& o, const std::string& where, const char* name) const {
    const json* v = field(o, where, name, false);
    if (!v) return {};
    if (!v->is_string()) fail(where + name, std::string("expected a string, found ") + kind(*v));
    return v->get<std::string>();
  }

 private:
  std::filesystem::path m_path;
};

}  // namespace

Report read_report(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("cannot open the report", path);
  json j;
  try {
    j = json::parse(in);
  } catch (const json::exception& e) {  // parse_error, or out_of_range for a number like 1e999
    throw InputError(std::string("not valid JSON: ") + e.what(), path);
  }
  const ReportFields rf(path);
  if (!j.is_object())
    rf.fail("", std::string("expected an object, found ") + ReportFields::kind(j));
  Report r;
  r.complete = rf.boolean(j, "", "complete", true);
  r.stopped_at = rf.integer(j, "", "stopped_at", false, -1);
  r.stopped_reason = rf.string(j, "", "stopped_reason");
  r.engine = rf.string(j, "", "engine");
  const json& frames = *rf.field(j, "", "frames", true);
  if (!frames.is_array())
    rf.fail("frames", std::string("expected a list, found ") + ReportFields::kind(frames));
  for (size_t i = 0; i < frames.size(); ++i) {
    const json& f = frames[i];
    const std::string where = "frames[" + std::to_string(i) + "].";
    if (!f.is_object())
      rf.fail(where.substr(0, where.size() - 1),
              std::string("expected an object, found ") + ReportFields::kind(f));
    FrameRecord x;
    x.index = rf.integer(f, where, "index", true, 0);
    x.violation_pct = rf.number(f, where, "violation_pct", true, 0.0);
    x.visible_area_px = rf.number(f, where, "visible_area_px", false, 0.0);
    x.control_force = rf.number(f, where, "control_force", true, 0.0);
    x.physical_force = rf.number(f, where, "physical_force", true, 0.0);
    x.solve_ms = rf.number(f, where, "solve_ms", false, 0.0);
    x.frame_ms = rf.number(f, where, "frame_ms", false, 0.0);
    x.iterations = rf.integer(f, where, "iterations", false, 0);
    x.status = rf.string(f, where, "status");
    x.pose_lost = rf.boolean(f, where, "pose_lost", false);
    x.substep_factor = rf.integer(f, where, "substep_factor", false, 1);
    r.frames.push_back(x);
  }
  if (const json* summary = rf.field(j, "", "summary", false); summary && summary->is_object()) {
    if (const json* w = rf.field(*summary, "summary.", "warnings", false)) {
      if (!w->is_array())
        rf.fail("summary.warnings",
                std::string("expected a list, found ") + ReportFields::kind(*w));
      for (size_t i = 0; i < w->size(); ++i) {
        if (!(*w)[i].is_string())
          rf.fail("summary.warnings[" + std::to_string(i) + "]",
                  std::string("expected a string, found ") + ReportFields::kind((*w)[i]));
        r.warnings.push_back((*w)[i].get<std::string>());
      }
    }
  }
  return r;
}

}  // namespace pbve
