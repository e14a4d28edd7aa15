#include "pbve/edit/report.hpp"

#include <algorithm>
#include <cmath>
#include <fstream>
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
  std::vector<double> ratios;
  for (const FrameRecord& f : frames) {
    s.violation_pct_mean += f.violation_pct;
    s.violation_pct_max = std::max(s.violation_pct_max, f.violation_pct);
    s.ms_per_frame_mean += f.frame_ms;
    s.solve_ms_mean += f.solve_ms;
    if (f.physical_force > 0.0) ratios.push_back(f.control_force / f.physical_force);
  }
  const double n = static_cast<double>(frames.size());
  s.violation_pct_mean /= n;
  s.ms_per_frame_mean /= n;
  s.solve_ms_mean /= n;
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
                  {"warnings", report.warnings}};
  j["settings"] = report.settings_yaml.empty() ? json::object()
                                               : yaml_to_json(YAML::Load(report.settings_yaml));
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    if (!out) throw InputError("cannot write the report", path);
    out << j.dump(2) << '\n';
    if (!out) throw InputError("failed while writing the report", path);
  });
}

Report read_report(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) throw InputError("cannot open the report", path);
  json j;
  try {
    j = json::parse(in);
  } catch (const json::parse_error& e) {
    throw InputError(std::string("not valid JSON: ") + e.what(), path);
  }
  Report r;
  try {
    r.complete = j.value("complete", true);
    r.stopped_at = j.value("stopped_at", -1);
    r.stopped_reason = j.value("stopped_reason", "");
    r.engine = j.value("engine", "");
    for (const json& f : j.at("frames")) {
      FrameRecord x;
      x.index = f.at("index").get<int>();
      x.violation_pct = f.at("violation_pct").get<double>();
      x.visible_area_px = f.value("visible_area_px", 0.0);
      x.control_force = f.at("control_force").get<double>();
      x.physical_force = f.at("physical_force").get<double>();
      x.solve_ms = f.value("solve_ms", 0.0);
      x.frame_ms = f.value("frame_ms", 0.0);
      x.iterations = f.value("iterations", 0);
      x.status = f.value("status", "");
      x.pose_lost = f.value("pose_lost", false);
      x.substep_factor = f.value("substep_factor", 1);
      r.frames.push_back(x);
    }
    if (j.contains("summary") && j["summary"].contains("warnings"))
      r.warnings = j["summary"]["warnings"].get<std::vector<std::string>>();
  } catch (const json::exception& e) {
    throw InputError(std::string("not a pbve report: ") + e.what(), path);
  }
  return r;
}

}  // namespace pbve
