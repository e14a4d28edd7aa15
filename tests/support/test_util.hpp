#pragma once
// Helpers shared by the tests.

#include <unistd.h>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/camera.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve::test {

/// A fresh empty directory for the running test (removed at destruction).
class TempDir {
 public:
  TempDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = info ? std::string(info->test_suite_name()) + "_" + info->name() : "pbve";
    for (char& c : name)
      if (c == '/') c = '_';
    m_path = std::filesystem::temp_directory_path() /
             ("pbve_test_" + name + "_" + std::to_string(::getpid()));
    std::filesystem::remove_all(m_path);
    std::filesystem::create_directories(m_path);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(m_path, ec);
  }
  const std::filesystem::path& path() const { return m_path; }
  std::filesystem::path operator/(const std::string& name) const { return m_path / name; }

 private:
  std::filesystem::path m_path;
};

/// Writes `text` to `path` and returns the path.
inline std::filesystem::path write_text(const std::filesystem::path& path,
                                        const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
  return path;
}

/// A pinhole camera of `width` x `height` pixels, focal length `f` pixels, principal point at
/// the image centre.
inline Camera centred_camera(int width, int height, double f) {
  Camera c;
  c.fx = c.fy = f;
  c.cx = (width - 1) / 2.0;
  c.cy = (height - 1) / 2.0;
  c.width = width;
  c.height = height;
  return c;
}

/// Directory of checked-in test data (tests/data).
inline std::filesystem::path data_dir() {
  return PBVE_TEST_DATA_DIR;
}

/// `v` bent about the y axis onto a cylinder of radius `radius` through z = 0: x becomes the arc
/// length, z the distance outwards from the cylinder (a board bent without stretching its
/// middle surface).
inline Vertices bent_about_y(Vertices v, double radius) {
  for (Eigen::Index i = 0; i < v.rows(); ++i) {
    const double theta = v(i, 0) / radius, r = radius + v(i, 2);
    v(i, 0) = r * std::sin(theta);
    v(i, 2) = r * std::cos(theta);
  }
  return v;
}

}  // namespace pbve::test
