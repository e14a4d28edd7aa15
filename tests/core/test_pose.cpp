#include "pbve/core/pose.hpp"

#include <cmath>
#include <numbers>
#include <string>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "support/test_util.hpp"

namespace {

using pbve::Pose;
using pbve::PoseTrack;
using pbve::test::TempDir;
using pbve::test::write_text;

constexpr double kEps = 1e-12;  // a few ulps on unit-magnitude rotation entries

TEST(Pose, ZeroRodriguesIsIdentity) {
  const Pose p = Pose::from_rodrigues(Eigen::Vector3d::Zero(), Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(p.rotation, Eigen::Matrix3d::Identity());
  EXPECT_EQ(p.rodrigues(), Eigen::Vector3d::Zero());
  EXPECT_EQ(Pose{}.rodrigues(), Eigen::Vector3d::Zero());
}

TEST(Pose, RodriguesMatrixRoundTrip) {
  const Eigen::Vector3d rvecs[] = {
      {0.1, -0.2, 0.3}, {1.0, 0.0, 0.0}, {0.0, 0.0, -2.5}, {1e-9, 2e-9, -1e-9}, {0.5, 1.2, -0.7}};
  for (const auto& r : rvecs) {
    const Pose p = Pose::from_rodrigues(r, Eigen::Vector3d(0.1, 0.2, 0.3));
    EXPECT_LT((p.rotation.transpose() * p.rotation - Eigen::Matrix3d::Identity()).norm(), kEps);
    EXPECT_NEAR(p.rotation.determinant(), 1.0, kEps);
    EXPECT_LT((p.rodrigues() - r).norm(), kEps) << r.transpose();
  }
}

TEST(Pose, RodriguesOfKnownRotation) {
  // 90 degrees about z maps x to y.
  const Pose p = Pose::from_rodrigues({0, 0, std::numbers::pi / 2}, Eigen::Vector3d::Zero());
  EXPECT_LT((p.apply(Eigen::Vector3d(1, 0, 0)) - Eigen::Vector3d(0, 1, 0)).norm(), kEps);
}

TEST(Pose, MatrixAndApplyAgree) {
  const Pose p = Pose::from_rodrigues({0.3, -0.4, 0.2}, {0.5, -1.0, 2.0});
  const Eigen::Matrix4d m = p.matrix();
  EXPECT_EQ(m.row(3), Eigen::RowVector4d(0, 0, 0, 1));
  pbve::Vertices v(3, 3);
  v << 1, 2, 3, -1, 0.5, 0, 0, 0, 0;
  const pbve::Vertices out = p.apply(v);
  ASSERT_EQ(out.rows(), 3);
  for (int i = 0; i < 3; ++i) {
    const Eigen::Vector4d h = m * Eigen::Vector4d(v(i, 0), v(i, 1), v(i, 2), 1.0);
    EXPECT_LT((out.row(i).transpose() - h.head<3>()).norm(), kEps);
    EXPECT_LT((out.row(i).transpose() - p.apply(Eigen::Vector3d(v.row(i).transpose()))).norm(),
              kEps);
  }
}

TEST(PoseTrack, LostCount) {
  PoseTrack t;
  t.poses = {Pose{}, std::nullopt, Pose{}, std::nullopt, std::nullopt};
  EXPECT_EQ(t.size(), 5);
  EXPECT_EQ(t.lost_count(), 3);
}

TEST(PoseFile, ParsesBothFormsLostAndComments) {
  TempDir dir;
  const auto path = write_text(dir / "poses.txt",
                               "# header comment\n"
                               "\n"
                               "1 0 0 0.5  0 1 0 -0.25  0 0 1 2  0 0 0 1   # identity + t\n"
                               "   \t\n"
                               "0 0 1.5707963267948966 0.1 0.2 3\r\n"
                               "lost\n"
                               "lost # unknown\n"
                               "0 0 0 0 0 0");
  const PoseTrack t = pbve::load_pose_file(path);
  ASSERT_EQ(t.size(), 5);
  EXPECT_EQ(t.lost_count(), 2);
  ASSERT_TRUE(t.poses[0]);
  EXPECT_EQ(t.poses[0]->rotation, Eigen::Matrix3d::Identity());
  EXPECT_EQ(t.poses[0]->translation, Eigen::Vector3d(0.5, -0.25, 2));
  ASSERT_TRUE(t.poses[1]);
  EXPECT_LT((t.poses[1]->apply(Eigen::Vector3d(1, 0, 0)) - Eigen::Vector3d(0.1, 1.2, 3)).norm(),
            kEps);
  EXPECT_FALSE(t.poses[2]);
  EXPECT_FALSE(t.poses[3]);
  ASSERT_TRUE(t.poses[4]);
  EXPECT_EQ(t.poses[4]->rotation, Eigen::Matrix3d::Identity());
}

TEST(PoseFile, ParseFromMemoryMatchesTheFileReader) {
  TempDir dir;
  const std::string good = "lost\n0 0 0.5 0.1 0.2 3\r\n# end\n";
  const std::string text = good + "1 0 0 0 0 1 0 0";  // a last line of 8 numbers
  const PoseTrack from_file = pbve::load_pose_file(write_text(dir / "poses.txt", good));
  // The text need not end in a null character: the view stops before the bad line.
  const PoseTrack from_memory =
      pbve::parse_pose_file(std::string_view(text).substr(0, good.size()), "mem.txt");
  ASSERT_EQ(from_memory.size(), 2);
  ASSERT_EQ(from_file.size(), 2);
  EXPECT_FALSE(from_memory.poses[0]);
  ASSERT_TRUE(from_memory.poses[1]);
  EXPECT_EQ(from_memory.poses[1]->matrix(), from_file.poses[1]->matrix());
  try {
    pbve::parse_pose_file(text, "named.txt");
    FAIL() << "expected InputError";
  } catch (const pbve::InputError& e) {
    EXPECT_EQ(e.file(), "named.txt");
    EXPECT_EQ(e.line(), 4);
  }
}

TEST(PoseFile, AcceptsRotationWithinTolerance) {
  TempDir dir;
  // Entries rounded to 6 digits, as many tools write them: off by ~5e-7.
  const auto path =
      write_text(dir / "p.txt", "0.540302 -0.841471 0 0 0.841471 0.540302 0 0 0 0 1 1 0 0 0 1\n");
  const PoseTrack t = pbve::load_pose_file(path);
  ASSERT_EQ(t.size(), 1);
  EXPECT_NEAR(t.poses[0]->rodrigues().z(), 1.0, 1e-5);
}

TEST(PoseFile, SaveLoadRoundTripIsBitExact) {
  TempDir dir;
  PoseTrack t;
  t.poses.push_back(Pose::from_rodrigues({0.1234567890123, -0.3, 2.9}, {1.0 / 3.0, -1e-17, 5e8}));
  t.poses.push_back(std::nullopt);
  t.poses.push_back(Pose::from_rodrigues({-1e-7, 0.0, 0.7}, {0.1, 0.2, 0.3}));
  const auto path = dir / "out.txt";
  pbve::save_pose_file(t, path);
  EXPECT_FALSE(std::filesystem::exists(pbve::partial_path(path)));
  const PoseTrack back = pbve::load_pose_file(path);
  ASSERT_EQ(back.size(), t.size());
  for (int i = 0; i < t.size(); ++i) {
    ASSERT_EQ(bool(back.poses[i]), bool(t.poses[i])) << i;
    if (!t.poses[i]) continue;
    EXPECT_EQ(back.poses[i]->rotation, t.poses[i]->rotation) << i;  // bit-exact
    EXPECT_EQ(back.poses[i]->translation, t.poses[i]->translation) << i;
  }
}

TEST(PoseFile, PartialPathKeepsExtension) {
  EXPECT_EQ(pbve::partial_path("dir/poses.txt"), std::filesystem::path("dir/poses.partial.txt"));
  EXPECT_EQ(pbve::partial_path("out.mp4"), std::filesystem::path("out.partial.mp4"));
  EXPECT_EQ(pbve::partial_path("noext"), std::filesystem::path("noext.partial"));
}

// ---- bad input: every error is an InputError naming the file and the line -----------------

/// Loads `text` as a pose file; expects an InputError at `line` (0: none) whose message
/// contains `fragment`.
void expect_bad(const std::string& text, int line, const std::string& fragment) {
  TempDir dir;
  const auto path = write_text(dir / "bad_poses.txt", text);
  try {
    pbve::load_pose_file(path);
    FAIL() << "expected InputError containing '" << fragment << "'";
  } catch (const pbve::InputError& e) {
    const std::string what = e.what();
    EXPECT_EQ(e.file(), path);
    EXPECT_EQ(e.line(), line);
    const std::string where =
        line > 0 ? path.string() + ":" + std::to_string(line) + ":" : path.string() + ":";
    EXPECT_EQ(what.rfind(where, 0), 0u) << what;
    EXPECT_NE(what.find(fragment), std::string::npos) << what;
  }
}

const std::string kGood16 = "1 0 0 0 0 1 0 0 0 0 1 1 0 0 0 1\n";

TEST(PoseFileBadInput, WrongNumberCount) {
  expect_bad(kGood16 + "# c\n1 2 3 4 5\n", 3, "expected 16 or 6 numbers or 'lost', found 5");
}

TEST(PoseFileBadInput, NonNumericToken) {
  expect_bad(kGood16 + "0 0 0 1 2 abc\n", 2, "value 6 is not a number: 'abc'");
  expect_bad("lots\n", 1, "expected 16 or 6 numbers or 'lost', found 'lots'");
}

TEST(PoseFileBadInput, NotFinite) {
  expect_bad("0 0 nan 1 2 3\n", 1, "value 3 is not finite");
  expect_bad(kGood16 + kGood16 + "1 0 0 inf 0 1 0 0 0 0 1 1 0 0 0 1\n", 3, "not finite");
}

// Breaks fuzz_pose's "poses are finite" expectation without the check
// (tests/fuzz/corpus/pose/regress_rotation_vector_overflow.txt): the angle was infinite and the
// rotation NaN, accepted as a pose.
TEST(PoseFileBadInput, RotationVectorWhoseLengthOverflows) {
  expect_bad(kGood16 + "1.7e308 1.7e308 1.7e308 0 0 1\n", 2, "rotation vector is too long");
}

TEST(PoseFileBadInput, TranslationFartherThanAnyFilmedObject) {
  // 1e20 m stopped the ray tracer on an assertion; the file's line says it instead.
  expect_bad(kGood16 + "0 0 0 0 0 1e20\n", 2, "the translation is 1e+20 m from the camera");
  expect_bad("1 0 0 0 0 1 0 -2e9 0 0 1 1 0 0 0 1\n", 1, "beyond 1e+09 m");
}

TEST(PoseFile, IgnoresAByteOrderMark) {
  EXPECT_EQ(pbve::parse_pose_file("\xEF\xBB\xBF" + kGood16, "p.txt").size(), 1);
}

TEST(PoseFileBadInput, NotARotation) {
  // A scale of 1.1 along x: R^T R - I has 0.21 on the diagonal.
  expect_bad("1.1 0 0 0 0 1 0 0 0 0 1 1 0 0 0 1\n", 1, "max |R^T R - I| = 0.21");
}

TEST(PoseFileBadInput, Reflection) {
  expect_bad(kGood16 + "-1 0 0 0 0 1 0 0 0 0 1 1 0 0 0 1\n", 2, "reflection");
}

TEST(PoseFileBadInput, BadLastRow) {
  expect_bad("1 0 0 0 0 1 0 0 0 0 1 1 0 0 1 1\n", 1, "last row of the matrix must be 0 0 0 1");
}

TEST(PoseFileBadInput, EmptyFile) {
  expect_bad("", 0, "no poses");
  expect_bad("# only a comment\n\n   \n", 0, "no poses");
}

TEST(PoseFileBadInput, MissingFile) {
  TempDir dir;
  const auto path = dir / "missing.txt";
  try {
    pbve::load_pose_file(path);
    FAIL() << "expected InputError";
  } catch (const pbve::InputError& e) {
    EXPECT_EQ(e.file(), path);
    EXPECT_NE(std::string(e.what()).find(path.string()), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("not found"), std::string::npos) << e.what();
  }
}

}  // namespace
