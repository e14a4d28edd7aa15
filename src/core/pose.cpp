#include "pbve/core/pose.hpp"

#include <charconv>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>
#include <string>
#include <string_view>

#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"

namespace pbve {

Vertices Pose::apply(const Vertices& v) const {
  Vertices out = v * rotation.transpose();
  out.rowwise() += translation.transpose();
  return out;
}

Eigen::Matrix4d Pose::matrix() const {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  m.topLeftCorner<3, 3>() = rotation;
  m.topRightCorner<3, 1>() = translation;
  return m;
}

Pose Pose::from_rodrigues(const Eigen::Vector3d& rvec, const Eigen::Vector3d& t) {
  Pose pose;
  pose.translation = t;
  const double angle = rvec.stableNorm();
  if (angle > 0.0) {
    pose.rotation = Eigen::AngleAxisd(angle, rvec / angle).toRotationMatrix();
  }  // else: identity (the zero rotation vector)
  return pose;
}

Eigen::Vector3d Pose::rodrigues() const {
  // AngleAxis goes through a quaternion; for the identity it yields angle 0 (axis arbitrary).
  const Eigen::AngleAxisd aa(rotation);
  return aa.axis() * aa.angle();
}

int PoseTrack::lost_count() const {
  int n = 0;
  for (const auto& p : poses)
    if (!p) ++n;
  return n;
}

namespace {

std::string format_number(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

std::vector<std::string_view> split_tokens(std::string_view s) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  const auto is_space = [](char c) {
    return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
  };
  while (i < s.size()) {
    while (i < s.size() && is_space(s[i])) ++i;
    const std::size_t start = i;
    while (i < s.size() && !is_space(s[i])) ++i;
    if (i > start) tokens.push_back(s.substr(start, i - start));
  }
  return tokens;
}

/// Checks that `r` is a rotation; returns an empty string when it is, else what is wrong.
std::string rotation_problem(const Eigen::Matrix3d& r) {
  const double det = r.determinant();
  const double orth = (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (det < 0.0)
    return "the 3x3 part is a reflection, not a rotation (determinant " + format_number(det) + ")";
  if (!(orth <= kRotationTolerance))
    return "the 3x3 part is not a rotation: max |R^T R - I| = " + format_number(orth) +
           " (tolerance " + format_number(kRotationTolerance) + ")";
  if (!(std::abs(det - 1.0) <= kRotationTolerance))
    return "the 3x3 part is not a rotation: determinant " + format_number(det) +
           " (expected 1 within " + format_number(kRotationTolerance) + ")";
  return {};
}

// Farther than this from the camera is no pose of filmed footage (the ray tracer's single
// precision fails long before: at 1e20 m it stops on an assertion).
constexpr double kMaxTranslation = 1e9;  // metres

void check_translation(const Eigen::Vector3d& t, const std::filesystem::path& path, int line) {
  if (!(t.norm() <= kMaxTranslation))
    throw InputError("the translation is " + format_number(t.norm()) +
                         " m from the camera, beyond " + format_number(kMaxTranslation) +
                         " m (units: metres)",
                     path, line);
}

std::optional<Pose> parse_pose_line(const std::vector<std::string_view>& tokens,
                                    const std::filesystem::path& path, int line) {
  if (tokens.size() == 1 && tokens[0] == "lost") return std::nullopt;
  std::vector<double> values;
  values.reserve(tokens.size());
  for (std::size_t i = 0; i < tokens.size(); ++i) {
    const std::string_view tok = tokens[i];
    std::string_view digits = tok;
    if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
    double v = 0.0;
    const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), v);
    if (ec != std::errc() || end != digits.data() + digits.size()) {
      if (tokens.size() == 1)
        throw InputError("expected 16 or 6 numbers or 'lost', found '" + std::string(tok) + "'",
                         path, line);
      throw InputError(
          "value " + std::to_string(i + 1) + " is not a number: '" + std::string(tok) + "'", path,
          line);
    }
    if (!std::isfinite(v))
      throw InputError(
          "value " + std::to_string(i + 1) + " is not finite: '" + std::string(tok) + "'", path,
          line);
    values.push_back(v);
  }
  if (values.size() == 6) {
    const Eigen::Vector3d rvec(values[0], values[1], values[2]);
    // Finite components can still have an infinite length (the angle): no rotation.
    if (!std::isfinite(rvec.stableNorm()))
      throw InputError("the rotation vector is too long: its length (the angle) overflows", path,
                       line);
    const Pose pose = Pose::from_rodrigues(rvec, {values[3], values[4], values[5]});
    check_translation(pose.translation, path, line);
    return pose;
  }
  if (values.size() != 16)
    throw InputError("expected 16 or 6 numbers or 'lost', found " + std::to_string(values.size()),
                     path, line);
  const Eigen::Map<const Eigen::Matrix<double, 4, 4, Eigen::RowMajor>> m(values.data());
  const Eigen::RowVector4d last = m.row(3);
  if ((last - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > kRotationTolerance) {
    std::ostringstream s;
    s << "the last row of the matrix must be 0 0 0 1, found " << last;
    throw InputError(s.str(), path, line);
  }
  Pose pose;
  pose.rotation = m.topLeftCorner<3, 3>();
  pose.translation = m.topRightCorner<3, 1>();
  if (const std::string problem = rotation_problem(pose.rotation); !problem.empty())
    throw InputError(problem, path, line);
  check_translation(pose.translation, path, line);
  return pose;
}

}  // namespace

PoseTrack parse_pose_file(std::string_view text, const std::filesystem::path& name) {
  PoseTrack track;
  int line = 0;
  if (text.substr(0, 3) == "\xEF\xBB\xBF") text.remove_prefix(3);  // a UTF-8 byte-order mark
  while (!text.empty()) {
    ++line;
    const std::size_t eol = text.find('\n');
    std::string_view content = text.substr(0, eol);
    text.remove_prefix(eol == std::string_view::npos ? text.size() : eol + 1);
    if (const auto hash = content.find('#'); hash != std::string_view::npos)
      content = content.substr(0, hash);
    const auto tokens = split_tokens(content);
    if (tokens.empty()) continue;
    track.poses.push_back(parse_pose_line(tokens, name, line));
  }
  if (track.poses.empty())
    throw InputError("no poses (the file is empty or holds only comments)", name);
  return track;
}

PoseTrack load_pose_file(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) throw InputError("pose file not found", path);
    throw InputError("cannot open pose file", path);
  }
  std::string text;
  char chunk[1 << 14];
  while (in.read(chunk, sizeof chunk) || in.gcount() > 0)
    text.append(chunk, static_cast<std::size_t>(in.gcount()));
  if (in.bad()) throw InputError("read error", path);
  return parse_pose_file(text, path);
}

void save_pose_file(const PoseTrack& track, const std::filesystem::path& path) {
  write_atomically(path, [&](const std::filesystem::path& tmp) {
    std::FILE* f = std::fopen(tmp.c_str(), "wb");
    if (!f) throw InputError("cannot write pose file", path);
    bool ok = true;
    for (const auto& pose : track.poses) {
      if (!pose) {
        ok = ok && std::fputs("lost\n", f) >= 0;
        continue;
      }
      const Eigen::Matrix4d m = pose->matrix();
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c)
          ok = ok && std::fprintf(f, c + r == 0 ? "%.17g" : " %.17g", m(r, c)) >= 0;
      ok = ok && std::fputc('\n', f) != EOF;
    }
    ok = (std::fclose(f) == 0) && ok;
    if (!ok) throw InputError("write error", path);
  });
}

}  // namespace pbve
