// Tests for pbve/core/mesh.hpp: readers, writers, validation, geometry and refinement.

#include "pbve/core/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "pbve/control/energy.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/thin_sheet.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/visibility/visibility.hpp"
#include "support/test_util.hpp"

namespace pbve {
namespace {

using test::TempDir;
using test::write_text;

/// Runs `fn`, expects an InputError and returns it (a default one when none was thrown).
template <class Fn>
InputError expect_input_error(Fn&& fn) {
  try {
    fn();
  } catch (const InputError& e) {
    return e;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected pbve::InputError, got another exception: " << e.what();
    return InputError("");
  }
  ADD_FAILURE() << "expected pbve::InputError, nothing was thrown";
  return InputError("");
}

bool contains(const std::string& s, const std::string& part) {
  return s.find(part) != std::string::npos;
}

/// An axis-aligned box [0, sx] x [0, sy] x [0, sz]: 8 vertices, 12 outward triangles.
Mesh make_box(double sx = 1, double sy = 1, double sz = 1) {
  Mesh m;
  m.vertices.resize(8, 3);
  for (int i = 0; i < 8; ++i)
    m.vertices.row(i) << (i & 1 ? sx : 0), (i & 2 ? sy : 0), (i & 4 ? sz : 0);
  m.triangles.resize(12, 3);
  m.triangles << 0, 2, 1, 1, 2, 3,  // z = 0, normal -z
      4, 5, 6, 5, 7, 6,             // z = sz, normal +z
      0, 1, 4, 1, 5, 4,             // y = 0, normal -y
      2, 6, 3, 3, 6, 7,             // y = sy, normal +y
      0, 4, 2, 2, 4, 6,             // x = 0, normal -x
      1, 3, 5, 3, 7, 5;             // x = sx, normal +x
  m.triangle_part.assign(12, 0);
  m.interior.assign(12, 0);
  m.part_names = {"default"};
  return m;
}

/// A regular tetrahedron-like closed mesh: 4 vertices, 4 outward triangles.
Mesh make_tetrahedron() {
  Mesh m;
  m.vertices.resize(4, 3);
  m.vertices << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  m.triangles.resize(4, 3);
  m.triangles << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  m.triangle_part.assign(4, 0);
  m.interior.assign(4, 0);
  m.part_names = {"default"};
  return m;
}

void expect_same_mesh(const Mesh& a, const Mesh& b) {
  ASSERT_EQ(a.num_vertices(), b.num_vertices());
  ASSERT_EQ(a.num_triangles(), b.num_triangles());
  EXPECT_TRUE(a.vertices == b.vertices) << "vertices differ";  // exact: shortest round-trip text
  EXPECT_TRUE(a.triangles == b.triangles) << "triangles differ";
  EXPECT_EQ(a.triangle_part, b.triangle_part);
  EXPECT_EQ(a.interior, b.interior);
  EXPECT_EQ(a.part_names, b.part_names);
}

// ---------------------------------------------------------------------------------------
// OBJ reading

TEST(MeshObj, QuadsAndPolygonsAreFanTriangulated) {
  TempDir dir;
  const auto path = write_text(dir / "quad.obj",
                               "# a quad and a pentagon\n"
                               "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 1.5 0\n"
                               "f 1 2 3 4\n"
                               "f 1 2 3 5 4\n");
  const Mesh m = load_obj(path);
  ASSERT_EQ(m.num_vertices(), 5);
  ASSERT_EQ(m.num_triangles(), 2 + 3);
  EXPECT_EQ(m.triangles.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.triangles.row(1), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(m.triangles.row(2), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.triangles.row(3), Eigen::RowVector3i(0, 2, 4));
  EXPECT_EQ(m.triangles.row(4), Eigen::RowVector3i(0, 4, 3));
  EXPECT_EQ(m.part_names, std::vector<std::string>{"default"});
  EXPECT_EQ(m.triangle_part, std::vector<int>(5, 0));
  EXPECT_EQ(m.interior, std::vector<std::uint8_t>(5, 0));
  EXPECT_DOUBLE_EQ(m.vertices(4, 1), 1.5);
}

TEST(MeshObj, GroupsBecomePartsAndInteriorGroupsAreFlagged) {
  TempDir dir;
  const auto path = write_text(dir / "parts.obj",
                               "o unused_object\n"
                               "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                               "g shell\n"
                               "f 1 2 3\n"
                               "g interior_crack\n"
                               "f 1 2 4\n"
                               "g shell\n"
                               "f 1 3 4\n"
                               "o piece2\n"
                               "usemtl interior_material\n"
                               "f 2 3 4\n"
                               "usemtl stone\n"
                               "f 3 2 4\n");
  const Mesh m = load_obj(path);
  ASSERT_EQ(m.num_triangles(), 5);
  EXPECT_EQ(m.part_names, (std::vector<std::string>{"shell", "interior_crack", "piece2"}));
  EXPECT_EQ(m.triangle_part, (std::vector<int>{0, 1, 0, 2, 2}));
  EXPECT_EQ(m.interior, (std::vector<std::uint8_t>{0, 1, 0, 1, 0}));
}

TEST(MeshObj, SlashFormsAndNegativeIndices) {
  TempDir dir;
  const auto path = write_text(dir / "forms.obj",
                               "v 0 0 0\r\nv 1 0 0\r\nv 0 1 0\r\n"
                               "vt 0 0\r\nvt 1 0\r\nvt 0 1\r\n"
                               "vn 0 0 1\r\n"
                               "f 1/1/1 2/2/1 3/3/1\r\n"
                               "f 1//1 2//1 3//1\r\n"
                               "f 1/1 2/2 3/3\r\n"
                               "v 1 1 0\r\n"
                               "f -3/-3/-1 -1/-1/-1 -2/-2/-1\r\n"
                               "v +2 -1e-3 .5\r\n"
                               "f\t-4 -3\t-1 # trailing comment\r\n");
  const Mesh m = load_obj(path);
  ASSERT_EQ(m.num_triangles(), 5);
  for (int f = 0; f < 3; ++f) EXPECT_EQ(m.triangles.row(f), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.triangles.row(3), Eigen::RowVector3i(1, 3, 2));
  EXPECT_EQ(m.triangles.row(4), Eigen::RowVector3i(1, 2, 4));
  EXPECT_EQ(m.vertices.row(4), Eigen::RowVector3d(2, -1e-3, 0.5));
}

TEST(MeshObj, LoadMeshChoosesByExtensionCaseInsensitive) {
  TempDir dir;
  const auto path = write_text(dir / "TRI.OBJ", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_EQ(load_mesh(path).num_triangles(), 1);
  const auto bad = write_text(dir / "tri.stl", "solid\n");
  const InputError e = expect_input_error([&] { load_mesh(bad); });
  EXPECT_EQ(e.file(), bad);
  EXPECT_TRUE(contains(e.what(), "tri.stl")) << e.what();
  EXPECT_TRUE(contains(e.message(), ".stl")) << e.what();
}

TEST(MeshObj, ParseFromMemoryMatchesTheFileReader) {
  TempDir dir;
  const std::string text = "g a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\ng b\nf 1 2 4\n";
  const auto path = write_text(dir / "mem.obj", text);
  expect_same_mesh(parse_obj(text, "mem.obj"), load_obj(path));
  // Errors name the given name; the text need not end in a null character.
  const std::string_view cut(text.data(), text.size() - 3);  // "f 1 2 4" becomes "f 1 2"
  const InputError e = expect_input_error([&] { parse_obj(cut, "named.obj"); });
  EXPECT_EQ(e.file(), "named.obj");
  EXPECT_EQ(e.line(), 8);
}

// ---------------------------------------------------------------------------------------
// OBJ bad input: every error names the file and the line

TEST(MeshObjBadInput, IndexOutOfRangeNamesLineIndexAndCount) {
  TempDir dir;
  const auto path = write_text(dir / "range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.line(), 5);
  EXPECT_TRUE(contains(e.what(), path.string() + ":5:")) << e.what();
  EXPECT_TRUE(contains(e.message(), "9")) << e.what();
  EXPECT_TRUE(contains(e.message(), "3 vertices")) << e.what();
}

TEST(MeshObjBadInput, NegativeIndexBeyondDefinedVertices) {
  TempDir dir;
  const auto path = write_text(dir / "neg.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.line(), 3);
  EXPECT_TRUE(contains(e.message(), "-3")) << e.what();
  EXPECT_TRUE(contains(e.message(), "2 vertices")) << e.what();
}

// Found by fuzz_obj (tests/fuzz/corpus/obj/regress_most_negative_index.obj): negating the most
// negative index overflowed.
TEST(MeshObjBadInput, MostNegativeIndexIsOutOfRange) {
  const InputError e = expect_input_error(
      [&] { parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 -9223372036854775808\n", "min.obj"); });
  EXPECT_EQ(e.line(), 4);
  EXPECT_TRUE(contains(e.message(), "-9223372036854775808")) << e.what();
  EXPECT_TRUE(contains(e.message(), "3 vertices")) << e.what();
}

TEST(MeshObjBadInput, MalformedNumberNamesLineAndToken) {
  TempDir dir;
  const auto path = write_text(dir / "num.obj", "v 0 0 0\nv 1 0 0\nv 0 1.2.3 0\nf 1 2 3\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.line(), 3);
  EXPECT_TRUE(contains(e.what(), "num.obj:3:")) << e.what();
  EXPECT_TRUE(contains(e.message(), "'1.2.3'")) << e.what();
}

TEST(MeshObjBadInput, MalformedFaceIndex) {
  TempDir dir;
  const auto path = write_text(dir / "face.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 3\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.line(), 4);
  EXPECT_TRUE(contains(e.message(), "'x'")) << e.what();
}

TEST(MeshObjBadInput, NanCoordinate) {
  TempDir dir;
  const auto path = write_text(dir / "nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.line(), 2);
  EXPECT_TRUE(contains(e.message(), "non-finite")) << e.what();
}

TEST(MeshObjBadInput, InfiniteCoordinate) {
  TempDir dir;
  const auto path = write_text(dir / "inf.obj", "v 0 0 0\nv 1 0 0\nv 0 1 1e999\nf 1 2 3\n");
  // 1e999 overflows: reported as a bad number or as non-finite, on line 3 either way.
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.line(), 3);
  EXPECT_TRUE(contains(e.message(), "1e999")) << e.what();
}

TEST(MeshObjBadInput, FaceWithTwoVertices) {
  TempDir dir;
  const auto path = write_text(dir / "two.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.line(), 5);
  EXPECT_TRUE(contains(e.message(), "2 vertices")) << e.what();
}

TEST(MeshObjBadInput, VertexWithTwoCoordinates) {
  TempDir dir;
  const auto path = write_text(dir / "short.obj", "v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.line(), 2);
  EXPECT_TRUE(contains(e.message(), "3 coordinates")) << e.what();
}

TEST(MeshObjBadInput, EmptyFile) {
  TempDir dir;
  const auto path = write_text(dir / "empty.obj", "# nothing here\n");
  const InputError e = expect_input_error([&] { load_obj(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_TRUE(contains(e.message(), "empty mesh")) << e.what();
  const auto zero_bytes = write_text(dir / "zero.obj", "");
  const InputError e0 = expect_input_error([&] { load_mesh(zero_bytes); });
  EXPECT_EQ(e0.file(), zero_bytes);
  EXPECT_TRUE(contains(e0.message(), "empty mesh")) << e0.what();
  const auto no_faces = write_text(dir / "points.obj", "v 0 0 0\nv 1 0 0\n");
  const InputError e2 = expect_input_error([&] { load_obj(no_faces); });
  EXPECT_TRUE(contains(e2.message(), "no faces")) << e2.what();
}

TEST(MeshObjBadInput, MissingFile) {
  TempDir dir;
  const auto path = dir / "does_not_exist.obj";
  const InputError e = expect_input_error([&] { load_mesh(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_TRUE(contains(e.what(), "does_not_exist.obj")) << e.what();
  EXPECT_TRUE(contains(e.message(), "cannot open")) << e.what();
}

// ---------------------------------------------------------------------------------------
// PLY reading

/// Appends the little-endian bytes of `v`.
template <class T>
void put(std::string& s, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  s.append(b, sizeof(T));
}

TEST(MeshPly, AsciiWithExtraPropertiesAndQuads) {
  TempDir dir;
  const auto path = write_text(dir / "ascii.ply",
                               "ply\n"
                               "format ascii 1.0\n"
                               "comment made by hand\n"
                               "element vertex 4\n"
                               "property float x\n"
                               "property float nx\n"
                               "property float y\n"
                               "property float z\n"
                               "property uchar red\n"
                               "element face 2\n"
                               "property list uchar int vertex_indices\n"
                               "property uchar interior\n"
                               "property int part\n"
                               "element edge 1\n"
                               "property int vertex1\n"
                               "property int vertex2\n"
                               "end_header\n"
                               "0 9 0 0 255\n"
                               "1 9 0 0 255\n"
                               "1 9 1 0 255\n"
                               "0 9 1 0.5 255\n"
                               "4 0 1 2 3 0 1\n"
                               "3 0 2 1 1 0\n"
                               "0 1\n");
  const Mesh m = load_ply(path);
  ASSERT_EQ(m.num_vertices(), 4);
  ASSERT_EQ(m.num_triangles(), 3);
  EXPECT_EQ(m.vertices.row(3), Eigen::RowVector3d(0, 1, 0.5));
  EXPECT_EQ(m.triangles.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.triangles.row(1), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(m.triangles.row(2), Eigen::RowVector3i(0, 2, 1));
  EXPECT_EQ(m.triangle_part, (std::vector<int>{1, 1, 0}));
  EXPECT_EQ(m.interior, (std::vector<std::uint8_t>{0, 0, 1}));
  EXPECT_EQ(m.num_parts(), 2);
}

/// A binary PLY of a unit right triangle plus a quad, with normals, colours and mixed types.
std::string binary_ply_with_extras(int faces_to_write = 2, bool truncate_last = false) {
  std::string s =
      "ply\n"
      "format binary_little_endian 1.0\n"
      "element vertex 4\n"
      "property double x\n"
      "property float nx\n"
      "property short s\n"
      "property float y\n"
      "property list uchar ushort weird\n"
      "property float z\n"
      "property uchar red\n"
      "property uint id\n"
      "element face 2\n"
      "property int flags\n"
      "property list int uint vertex_indices\n"
      "property char interior\n"
      "end_header\n";
  const double xs[4] = {0, 1, 1, 0};
  const float ys[4] = {0, 0, 1, 1};
  for (int i = 0; i < 4; ++i) {
    put<double>(s, xs[i]);
    put<float>(s, 0.5f);
    put<std::int16_t>(s, -7);
    put<float>(s, ys[i]);
    put<std::uint8_t>(s, 2);
    put<std::uint16_t>(s, 11);
    put<std::uint16_t>(s, 12);
    put<float>(s, 0.25f * i);
    put<std::uint8_t>(s, 200);
    put<std::uint32_t>(s, 1000u + i);
  }
  if (faces_to_write >= 1) {
    put<std::int32_t>(s, 42);
    put<std::int32_t>(s, 3);
    for (std::uint32_t v : {0u, 1u, 2u}) put<std::uint32_t>(s, v);
    put<std::int8_t>(s, 1);
  }
  if (faces_to_write >= 2) {
    put<std::int32_t>(s, 43);
    put<std::int32_t>(s, 4);
    for (std::uint32_t v : {0u, 1u, 2u, 3u}) put<std::uint32_t>(s, v);
    put<std::int8_t>(s, 0);
  }
  if (truncate_last) s.resize(s.size() - 3);
  return s;
}

TEST(MeshPly, BinaryLittleEndianSkipsExtraPropertiesOfAllTypes) {
  TempDir dir;
  const auto path = write_text(dir / "extras.ply", binary_ply_with_extras());
  const Mesh m = load_mesh(path);
  ASSERT_EQ(m.num_vertices(), 4);
  ASSERT_EQ(m.num_triangles(), 3);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(m.vertices(i, 2), 0.25 * i);
  EXPECT_EQ(m.vertices.row(2), Eigen::RowVector3d(1, 1, 0.5));
  EXPECT_EQ(m.triangles.row(0), Eigen::RowVector3i(0, 1, 2));
  EXPECT_EQ(m.triangles.row(2), Eigen::RowVector3i(0, 2, 3));
  EXPECT_EQ(m.interior, (std::vector<std::uint8_t>{1, 0, 0}));
  EXPECT_EQ(m.part_names, std::vector<std::string>{"default"});
}

// ---------------------------------------------------------------------------------------
// PLY bad input: every error names the file and the header line, body line or element

TEST(MeshPlyBadInput, BadHeaderLine) {
  TempDir dir;
  const auto path = write_text(dir / "header.ply",
                               "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                               "propertee float y\nend_header\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.line(), 5);
  EXPECT_TRUE(contains(e.what(), "header.ply:5:")) << e.what();
  EXPECT_TRUE(contains(e.message(), "propertee")) << e.what();
}

TEST(MeshPlyBadInput, BadElementCount) {
  TempDir dir;
  const auto path =
      write_text(dir / "count.ply", "ply\nformat ascii 1.0\nelement vertex three\nend_header\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.line(), 3);
  EXPECT_TRUE(contains(e.message(), "'three'")) << e.what();
}

TEST(MeshPlyBadInput, BigEndianIsUnsupported) {
  TempDir dir;
  const auto path = write_text(dir / "big.ply",
                               "ply\nformat binary_big_endian 1.0\nelement vertex 0\nend_header\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.line(), 2);
  EXPECT_TRUE(contains(e.message(), "binary_big_endian")) << e.what();
  EXPECT_TRUE(contains(e.message(), "unsupported")) << e.what();
}

TEST(MeshPlyBadInput, TruncatedBinaryNamesTheElement) {
  TempDir dir;
  const auto path = write_text(dir / "trunc.ply", binary_ply_with_extras(2, true));
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.key(), "face 1");
  EXPECT_TRUE(contains(e.what(), "trunc.ply")) << e.what();
  EXPECT_TRUE(contains(e.message(), "truncated")) << e.what();
  // Cut inside the vertex data.
  std::string s = binary_ply_with_extras(0);
  s.resize(s.size() - 20);  // each vertex record is 32 bytes
  const auto path2 = write_text(dir / "trunc2.ply", s);
  const InputError e2 = expect_input_error([&] { load_ply(path2); });
  EXPECT_EQ(e2.key(), "vertex 3");
}

TEST(MeshPlyBadInput, BinaryFaceIndexOutOfRange) {
  TempDir dir;
  std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 2\n"
      "property list uchar int vertex_indices\nend_header\n";
  for (int i = 0; i < 9; ++i) put<float>(s, static_cast<float>(i == 3 || i == 7));
  put<std::uint8_t>(s, 3);
  for (int v : {0, 1, 2}) put<std::int32_t>(s, v);
  put<std::uint8_t>(s, 3);
  for (int v : {0, 1, 3}) put<std::int32_t>(s, v);
  const auto path = write_text(dir / "range.ply", s);
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_EQ(e.key(), "face 1");
  EXPECT_TRUE(contains(e.what(), "range.ply: face 1:")) << e.what();
  EXPECT_TRUE(contains(e.message(), "vertex index 3")) << e.what();
  EXPECT_TRUE(contains(e.message(), "3 vertices")) << e.what();
}

TEST(MeshPlyBadInput, AsciiFaceIndexOutOfRangeNamesLineAndElement) {
  TempDir dir;
  const auto path = write_text(dir / "range_ascii.ply",
                               "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                               "property float y\nproperty float z\nelement face 1\n"
                               "property list uchar int vertex_indices\nend_header\n"
                               "0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.line(), 13);
  EXPECT_EQ(e.key(), "face 0");
  EXPECT_TRUE(contains(e.message(), "-1")) << e.what();
}

TEST(MeshPlyBadInput, AsciiMalformedNumberAndNan) {
  TempDir dir;
  const std::string header =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n";
  const auto path = write_text(dir / "num.ply", header + "0 0 0\n1 O 0\n0 1 0\n3 0 1 2\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.line(), 11);
  EXPECT_EQ(e.key(), "vertex 1");
  EXPECT_TRUE(contains(e.message(), "'O'")) << e.what();
  const auto path2 = write_text(dir / "nan.ply", header + "0 0 0\n1 0 0\n0 1 nan\n3 0 1 2\n");
  const InputError e2 = expect_input_error([&] { load_ply(path2); });
  EXPECT_EQ(e2.line(), 12);
  EXPECT_EQ(e2.key(), "vertex 2");
  EXPECT_TRUE(contains(e2.message(), "non-finite")) << e2.what();
}

TEST(MeshPlyBadInput, AsciiPartIdOutOfRange) {
  TempDir dir;
  const auto path = write_text(dir / "part.ply",
                               "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                               "property float y\nproperty float z\nelement face 1\n"
                               "property list uchar int vertex_indices\nproperty int part\n"
                               "end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2 2000000000\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.line(), 14);
  EXPECT_EQ(e.key(), "face 0");
  EXPECT_TRUE(contains(e.message(), "2000000000")) << e.what();
}

TEST(MeshPlyBadInput, AsciiEndOfFileInsideElement) {
  TempDir dir;
  const auto path = write_text(dir / "short.ply",
                               "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                               "property float y\nproperty float z\nend_header\n"
                               "0 0 0\n1 0 0\n0 1\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.key(), "vertex 2");
  EXPECT_EQ(e.line(), 10);
  EXPECT_TRUE(contains(e.message(), "end of file")) << e.what();
}

/// An ASCII PLY header of `vertices` x-y-z vertices and `faces` faces (then `body`).
std::string ascii_ply(const std::string& vertices, const std::string& faces,
                      const std::string& face_properties, const std::string& body) {
  return "ply\nformat ascii 1.0\nelement vertex " + vertices +
         "\nproperty float x\nproperty float y\nproperty float z\nelement face " + faces +
         "\nproperty list uchar int vertex_indices\n" + face_properties + "end_header\n" + body;
}

// Found by fuzz_ply (corpus/ply/regress_end_header_without_newline.ply): the body started one
// byte past the end of the data.
TEST(MeshPlyBadInput, EndHeaderWithoutNewlineIsTruncatedData) {
  const std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty double x\n"
      "property double y\nproperty double z\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header";
  const InputError e = expect_input_error([&] { parse_ply(s, "nl.ply"); });
  EXPECT_EQ(e.key(), "vertex 0");
  EXPECT_TRUE(contains(e.message(), "truncated")) << e.what();
}

// Counts in the header are not trusted for allocation: a small file declaring two billion
// entries is truncated data, not an attempt to allocate 48 GB.
TEST(MeshPlyBadInput, CountsBeyondTheDataAreTruncatedData) {
  const InputError e = expect_input_error(
      [&] { parse_ply(ascii_ply("2000000000", "1", "", "0 0 0\n1 0 0\n"), "v.ply"); });
  EXPECT_EQ(e.key(), "vertex 2");
  EXPECT_TRUE(contains(e.message(), "end of file")) << e.what();
  std::string s =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
      "property float y\nproperty float z\nelement face 2000000000\n"
      "property list uchar int vertex_indices\nend_header\n";
  for (float c : {0.f, 0.f, 0.f, 1.f, 0.f, 0.f, 0.f, 1.f, 0.f}) put<float>(s, c);
  put<std::uint8_t>(s, 3);
  for (int v : {0, 1, 2}) put<std::int32_t>(s, v);
  const InputError e2 = expect_input_error([&] { parse_ply(s, "f.ply"); });
  EXPECT_EQ(e2.key(), "face 1");
  EXPECT_TRUE(contains(e2.message(), "truncated")) << e2.what();
}

// An element without properties takes no space, however many entries it declares.
TEST(MeshPly, ElementWithoutPropertiesIsSkipped) {
  const std::string s =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement nothing 2000000000\nelement face 1\n"
      "property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const Mesh m = parse_ply(s, "empty_element.ply");
  EXPECT_EQ(m.num_vertices(), 3);
  EXPECT_EQ(m.triangles.row(0), Eigen::RowVector3i(0, 1, 2));
}

// ASCII integers outside their declared type were converted to 64-bit integers from doubles
// (undefined for 2^63) and looped over as list lengths.
TEST(MeshPlyBadInput, AsciiIntegersOutsideTheirTypeAreErrors) {
  const std::string vertices = "0 0 0\n1 0 0\n0 1 0\n";
  const InputError e = expect_input_error([&] {
    parse_ply(ascii_ply("3", "1", "", vertices + "9223372036854775807 0 1 2\n"), "count.ply");
  });
  EXPECT_EQ(e.line(), 13);
  EXPECT_EQ(e.key(), "face 0");
  EXPECT_TRUE(contains(e.message(), "9223372036854775807 out of range for type uchar")) << e.what();
  const InputError e2 = expect_input_error(
      [&] { parse_ply(ascii_ply("3", "1", "", vertices + "3 0 1 4294967296\n"), "i.ply"); });
  EXPECT_TRUE(contains(e2.message(), "out of range for type int")) << e2.what();
}

// A part id read as a float is named as it is (it was converted to an integer first).
TEST(MeshPlyBadInput, NonIntegerPartIdIsNamedAsRead) {
  const std::string s =
      ascii_ply("3", "1", "property float part\n", "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 1e300\n");
  const InputError e = expect_input_error([&] { parse_ply(s, "part.ply"); });
  EXPECT_EQ(e.key(), "face 0");
  EXPECT_TRUE(contains(e.message(), "invalid part id 1e+300")) << e.what();
}

// A coordinate given twice left another uninitialized; a second vertex element is ambiguous.
TEST(MeshPlyBadInput, RepeatedCoordinateOrElementIsAnError) {
  const InputError e = expect_input_error([&] {
    parse_ply(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float x\n"
        "property float y\nend_header\n0 0 0\n",
        "xx.ply");
  });
  EXPECT_TRUE(contains(e.message(), "x, y and z, once each")) << e.what();
  const InputError e2 = expect_input_error([&] {
    parse_ply(
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nelement vertex 1\n"
        "end_header\n",
        "vv.ply");
  });
  EXPECT_EQ(e2.line(), 5);
  EXPECT_TRUE(contains(e2.message(), "a second 'vertex' element")) << e2.what();
}

TEST(MeshPlyBadInput, NotAPlyFileAndMissingFaces) {
  TempDir dir;
  const auto path = write_text(dir / "obj_really.ply", "v 0 0 0\n");
  const InputError e = expect_input_error([&] { load_ply(path); });
  EXPECT_EQ(e.line(), 1);
  const auto empty = write_text(dir / "nofaces.ply",
                                "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
                                "property float y\nproperty float z\nend_header\n0 0 0\n");
  const InputError e2 = expect_input_error([&] { load_ply(empty); });
  EXPECT_EQ(e2.file(), empty);
  EXPECT_TRUE(contains(e2.message(), "empty mesh")) << e2.what();
}

// ---------------------------------------------------------------------------------------
// Round trips

Mesh make_two_part_mesh_with_interior() {
  Mesh box = make_box(0.3, 1.0 / 3.0, 2.5e-7);
  Mesh m = box;
  // Append a shifted copy as a second part; flag some faces interior.
  m.vertices.conservativeResize(16, 3);
  m.vertices.bottomRows(8) = box.vertices.rowwise() + Eigen::RowVector3d(1e10, -0.1, 3);
  m.triangles.conservativeResize(24, 3);
  m.triangles.bottomRows(12) = box.triangles.array() + 8;
  m.part_names = {"outer shell", "interior_piece", "crack"};
  m.triangle_part.assign(24, 0);
  for (int f = 12; f < 24; ++f) m.triangle_part[f] = f < 18 ? 2 : 1;
  m.interior.assign(24, 0);
  m.interior[3] = 1;  // interior face inside a non-interior part
  for (int f = 18; f < 24; ++f) m.interior[f] = 1;
  return m;
}

TEST(MeshRoundTrip, ObjPreservesEverything) {
  TempDir dir;
  const Mesh m = make_two_part_mesh_with_interior();
  const auto path = dir / "round.obj";
  save_obj(m, path);
  EXPECT_FALSE(std::filesystem::exists(dir / "round.partial.obj"));
  expect_same_mesh(load_mesh(path), m);
}

TEST(MeshRoundTrip, PlyPreservesEverything) {
  TempDir dir;
  const Mesh m = make_two_part_mesh_with_interior();
  const auto path = dir / "round.ply";
  save_ply(m, path);
  EXPECT_FALSE(std::filesystem::exists(dir / "round.partial.ply"));
  expect_same_mesh(load_mesh(path), m);
}

TEST(MeshRoundTrip, SaveRefusesEmptyMeshAndLeavesNoFile) {
  TempDir dir;
  const auto path = dir / "empty.ply";
  const InputError e = expect_input_error([&] { save_ply(Mesh{}, path); });
  EXPECT_EQ(e.file(), path);
  EXPECT_FALSE(std::filesystem::exists(path));
}

// ---------------------------------------------------------------------------------------
// Geometry

TEST(MeshGeometry, NormalsAreasCentroidsOfKnownTriangles) {
  Vertices v(4, 3);
  v << 0, 0, 0, 2, 0, 0, 0, 3, 0, 0, 0, 4;
  Triangles t(2, 3);
  t << 0, 1, 2,  // in z = 0, counter-clockwise from +z
      0, 3, 1;   // in y = 0
  const Vertices n = triangle_normals(v, t);
  EXPECT_EQ(n.row(0), Eigen::RowVector3d(0, 0, 6));
  EXPECT_EQ(n.row(1), Eigen::RowVector3d(0, 8, 0));  // (0,0,4) x (2,0,0) = (0,8,0)
  const Eigen::VectorXd a = triangle_areas(v, t);
  EXPECT_DOUBLE_EQ(a[0], 3.0);
  EXPECT_DOUBLE_EQ(a[1], 4.0);
  const Vertices c = triangle_centroids(v, t);
  EXPECT_TRUE(c.row(0).isApprox(Eigen::RowVector3d(2.0 / 3, 1, 0), 1e-15));
  EXPECT_TRUE(c.row(1).isApprox(Eigen::RowVector3d(2.0 / 3, 0, 4.0 / 3), 1e-15));
}

TEST(MeshGeometry, BoxNormalsPointOutward) {
  const Mesh box = make_box();
  const Vertices n = triangle_normals(box.vertices, box.triangles);
  const Vertices c = triangle_centroids(box.vertices, box.triangles);
  const Eigen::RowVector3d center(0.5, 0.5, 0.5);
  for (int f = 0; f < box.num_triangles(); ++f)
    EXPECT_GT(n.row(f).dot(c.row(f) - center), 0.0) << "triangle " << f;
  EXPECT_DOUBLE_EQ(triangle_areas(box.vertices, box.triangles).sum(), 6.0);
  EXPECT_DOUBLE_EQ(max_edge_length(box), std::sqrt(2.0));
}

TEST(MeshGeometry, TetrahedronAdjacency) {
  const Mesh tet = make_tetrahedron();
  const auto adj = vertex_adjacency(tet.triangles, tet.num_vertices());
  ASSERT_EQ(adj.size(), 4u);
  EXPECT_EQ(adj[0], (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(adj[1], (std::vector<int>{0, 2, 3}));
  EXPECT_EQ(adj[2], (std::vector<int>{0, 1, 3}));
  EXPECT_EQ(adj[3], (std::vector<int>{0, 1, 2}));
  // An isolated extra vertex has no neighbours.
  EXPECT_TRUE(vertex_adjacency(tet.triangles, 5)[4].empty());
}

TEST(MeshGeometry, FirstBoundaryEdgeFindsAHole) {
  Mesh tet = make_tetrahedron();
  EXPECT_FALSE(first_boundary_edge(tet.triangles).has_value());
  const Triangles open = tet.triangles.topRows(3);  // one face removed: its three edges
  const auto edge = first_boundary_edge(open);
  ASSERT_TRUE(edge.has_value());
  const Eigen::RowVector3i gone = tet.triangles.row(3);
  EXPECT_LT(edge->first, edge->second);
  EXPECT_TRUE((gone.array() == edge->first).any() && (gone.array() == edge->second).any());
}

TEST(MeshGeometry, OutOfRangeTriangleIndicesAreRefusedBeforeAnyRead) {
  const Mesh tet = make_tetrahedron();
  for (const int bad : {4, -1}) {
    Triangles t = tet.triangles;
    t(2, 1) = bad;
    const auto names = [&](const std::function<void()>& call, const std::string& who) {
      try {
        call();
        ADD_FAILURE() << who << ": no error for index " << bad;
      } catch (const std::invalid_argument& e) {
        const std::string m = e.what();
        EXPECT_NE(m.find(who + ": triangle 2 has vertex index " + std::to_string(bad) +
                         " outside [0, 4)"),
                  std::string::npos)
            << m;
      }
    };
    const Vertices& v = tet.vertices;
    names([&] { triangle_normals(v, t); }, "triangle_normals");
    names([&] { triangle_areas(v, t); }, "triangle_areas");
    names([&] { triangle_centroids(v, t); }, "triangle_centroids");
    names([&] { enclosed_volume(v, t); }, "enclosed_volume");
    names([&] { opposite_layer_pairs(v, t, 1.0); }, "opposite_layer_pairs");
    names([&] { make_thin_sheet(v, t, 1.0); }, "opposite_layer_pairs");
    names([&] { facing_values(v, t); }, "facing_values");
    names([&] { visibility_weights(v, t); }, "visibility_weights");
    Mesh m = tet;
    m.triangles = t;
    pbve::test::TempDir dir;
    EXPECT_THROW(save_obj(m, dir / "m.obj"), InputError);
    EXPECT_THROW(save_ply(m, dir / "m.ply"), InputError);
    EXPECT_FALSE(std::filesystem::exists(dir / "m.obj"));
  }
  EXPECT_NO_THROW(check_triangle_indices(tet.triangles, 4, "tet"));
  EXPECT_NO_THROW(check_triangle_indices(Triangles(0, 3), 0, "empty"));
}

TEST(MeshGeometry, ScaleAboutCentroidScalesDistancesAndKeepsCentroid) {
  Mesh m = make_box(2, 1, 0.5);
  m.vertices.rowwise() += Eigen::RowVector3d(3, -4, 5);
  const Mesh before = m;
  auto centroid = [](const Mesh& mesh) {
    const Eigen::VectorXd a = triangle_areas(mesh.vertices, mesh.triangles);
    const Vertices c = triangle_centroids(mesh.vertices, mesh.triangles);
    return Eigen::RowVector3d((a.transpose() * c) / a.sum());
  };
  scale_about_centroid(m, 1.01);
  const Eigen::RowVector3d c0 = centroid(before), c1 = centroid(m);
  EXPECT_LT((c1 - c0).norm(), 1e-13);
  EXPECT_TRUE(c0.isApprox(Eigen::RowVector3d(4, -3.5, 5.25), 1e-15));
  for (int i = 0; i < 8; ++i)
    for (int j = i + 1; j < 8; ++j) {
      const double d0 = (before.vertices.row(i) - before.vertices.row(j)).norm();
      const double d1 = (m.vertices.row(i) - m.vertices.row(j)).norm();
      // Coordinates of magnitude ~6, distances >= 0.5: a few ulps of 6 relative to d0.
      EXPECT_NEAR(d1, 1.01 * d0, 1e-13 * d0);
    }
  EXPECT_THROW(scale_about_centroid(m, 0.0), std::invalid_argument);
}

// ---------------------------------------------------------------------------------------
// Validation

TEST(MeshValidate, ClosedBoxIsOk) {
  const MeshReport r = validate_mesh(make_box());
  EXPECT_TRUE(r.ok());
  EXPECT_EQ(r.boundary_edge_count, 0);
  EXPECT_EQ(r.summary(), "");
}

TEST(MeshValidate, ReportsDegenerateTrianglesWithFirstIds) {
  Mesh m = make_tetrahedron();
  m.vertices.conservativeResize(6, 3);
  m.vertices.row(4) << 2, 0, 0;  // collinear with vertices 0 and 1
  m.vertices.row(5) << 0, 0, 0;  // coincides with vertex 0
  m.triangles.conservativeResize(7, 3);
  m.triangles.row(4) << 0, 1, 4;
  m.triangles.row(5) << 2, 2, 3;
  m.triangles.row(6) << 0, 5, 2;
  m.triangle_part.assign(7, 0);
  m.interior.assign(7, 0);
  const MeshReport r = validate_mesh(m);
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.degenerate_count, 3);
  EXPECT_EQ(r.degenerate_first, (std::vector<int>{4, 5, 6}));
  EXPECT_TRUE(contains(r.summary(), "3 degenerate triangles (first: 4, 5, 6)")) << r.summary();
}

TEST(MeshValidate, ReportsNonManifoldEdgesWithFirstIds) {
  Mesh m = make_tetrahedron();
  // Two fins on edge 0-1 and one on edge 2-3 of the tetrahedron.
  m.vertices.conservativeResize(7, 3);
  m.vertices.row(4) << 0.5, -1, 0;
  m.vertices.row(5) << 0.5, -1, 1;
  m.vertices.row(6) << 2, 2, 2;
  m.triangles.conservativeResize(7, 3);
  m.triangles.row(4) << 0, 1, 4;
  m.triangles.row(5) << 1, 0, 5;
  m.triangles.row(6) << 2, 3, 6;
  m.triangle_part.assign(7, 0);
  m.interior.assign(7, 0);
  const MeshReport r = validate_mesh(m);
  EXPECT_FALSE(r.ok());
  EXPECT_EQ(r.degenerate_count, 0);
  EXPECT_EQ(r.non_manifold_edge_count, 2);
  EXPECT_EQ(r.non_manifold_first, (std::vector<std::pair<int, int>>{{0, 1}, {2, 3}}));
  EXPECT_GT(r.boundary_edge_count, 0);
  EXPECT_TRUE(contains(r.summary(), "2 non-manifold edges")) << r.summary();
  EXPECT_TRUE(contains(r.summary(), "0-1, 2-3")) << r.summary();
}

TEST(MeshValidate, FatalProblemsNameTheElement) {
  TempDir dir;
  const auto src = dir / "src.obj";
  Mesh m = make_tetrahedron();
  m.triangles(2, 1) = 7;
  InputError e = expect_input_error([&] { validate_mesh(m, src); });
  EXPECT_EQ(e.file(), src);
  EXPECT_EQ(e.key(), "triangle 2");
  EXPECT_TRUE(contains(e.message(), "7")) << e.what();
  EXPECT_TRUE(contains(e.message(), "4 vertices")) << e.what();

  m = make_tetrahedron();
  m.vertices(3, 1) = std::numeric_limits<double>::infinity();
  e = expect_input_error([&] { validate_mesh(m, src); });
  EXPECT_EQ(e.key(), "vertex 3");

  m = make_tetrahedron();
  m.interior.pop_back();
  e = expect_input_error([&] { validate_mesh(m, src); });
  EXPECT_TRUE(contains(e.message(), "interior")) << e.what();

  e = expect_input_error([&] { validate_mesh(Mesh{}, src); });
  EXPECT_TRUE(contains(e.message(), "empty")) << e.what();
}

// ---------------------------------------------------------------------------------------
// Refinement

double total_area(const Mesh& m) {
  return triangle_areas(m.vertices, m.triangles).sum();
}

TEST(MeshRefine, UnitBoxToTenthKeepsShapeAndClosedness) {
  const Mesh box = make_box();
  const Mesh r = refine_mesh(box, 0.1);
  EXPECT_LE(max_edge_length(r), 0.1);
  // Area 6 covered by triangles of at most the equilateral area for edge 0.1.
  EXPECT_GT(r.num_triangles(), 6.0 / (0.01 * std::sqrt(3.0) / 4.0));
  EXPECT_NEAR(total_area(r), 6.0, 6.0 * 1e-12);
  ASSERT_GE(r.num_vertices(), 8);
  EXPECT_TRUE(r.vertices.topRows(8) == box.vertices);
  const MeshReport rep = validate_mesh(r);
  EXPECT_EQ(rep.boundary_edge_count, 0);
  EXPECT_EQ(rep.non_manifold_edge_count, 0);
  EXPECT_EQ(rep.degenerate_count, 0);
  // Every vertex lies on the box surface and normals still point outward.
  const Vertices n = triangle_normals(r.vertices, r.triangles);
  const Vertices c = triangle_centroids(r.vertices, r.triangles);
  for (int f = 0; f < r.num_triangles(); ++f)
    ASSERT_GT(n.row(f).dot(c.row(f) - Eigen::RowVector3d(0.5, 0.5, 0.5)), 0.0) << f;
  // Closed and consistently oriented: V - E + F = 2 with E = 3F / 2.
  EXPECT_EQ(r.num_vertices() - 3 * r.num_triangles() / 2 + r.num_triangles(), 2);
}

TEST(MeshRefine, AVertexCapStopsBeforeTheMemoryGoes) {
  const Mesh box = make_box();
  const Mesh r = refine_mesh(box, 0.1);
  // A cap at the result's size changes nothing; one below it throws before allocating.
  const Mesh capped = refine_mesh(box, 0.1, r.num_vertices());
  EXPECT_TRUE(capped.vertices == r.vertices);
  EXPECT_TRUE(capped.triangles == r.triangles);
  EXPECT_THROW(refine_mesh(box, 0.1, r.num_vertices() - 1), std::length_error);
  // A length in micrometres where metres are meant: stopped at the cap, not after billions.
  EXPECT_THROW(refine_mesh(box, 1e-6, 100000), std::length_error);
}

TEST(MeshRefine, PartsAndInteriorFlagsAreInherited) {
  Mesh m = make_two_part_mesh_with_interior();
  m.vertices = m.vertices.topRows(8).eval();  // both parts on the same 8 vertices
  m.triangles.bottomRows(12) = m.triangles.bottomRows(12).array() - 8;
  // Parts 0 and 2 on different triangles; mark triangle 3 interior.
  const Mesh r = refine_mesh(m, 0.05);
  EXPECT_LE(max_edge_length(r), 0.05);
  EXPECT_EQ(r.part_names, m.part_names);
  // Each original triangle's area is kept by its part/interior class.
  auto area_by = [](const Mesh& mesh, int part, int in) {
    const Eigen::VectorXd a = triangle_areas(mesh.vertices, mesh.triangles);
    double s = 0;
    for (int f = 0; f < mesh.num_triangles(); ++f)
      if (mesh.triangle_part[f] == part && mesh.interior[f] == in) s += a[f];
    return s;
  };
  for (int part = 0; part < 3; ++part)
    for (int in = 0; in < 2; ++in) {
      const double a0 = area_by(m, part, in);
      EXPECT_NEAR(area_by(r, part, in), a0, 1e-12 * std::max(a0, 1e-30)) << part << " " << in;
    }
  EXPECT_GT(area_by(r, 0, 1), 0.0);
}

TEST(MeshRefine, TwoSeparatePartsKeepTheirIds) {
  const Mesh m = make_two_part_mesh_with_interior();
  Mesh two = m;
  two.vertices.bottomRows(8) = m.vertices.topRows(8).rowwise() + Eigen::RowVector3d(2, 0, 0);
  const Mesh r = refine_mesh(two, 0.08);
  EXPECT_LE(max_edge_length(r), 0.08);
  EXPECT_TRUE(r.vertices.topRows(16) == two.vertices);
  for (int f = 0; f < r.num_triangles(); ++f) {
    // Part 0 lives at x < 1, parts 1 and 2 at x >= 2.
    const bool first = r.vertices(r.triangles(f, 0), 0) < 1.0;
    if (first)
      ASSERT_EQ(r.triangle_part[f], 0) << f;
    else
      ASSERT_NE(r.triangle_part[f], 0) << f;
  }
  const MeshReport rep = validate_mesh(r);
  EXPECT_EQ(rep.boundary_edge_count, 0);
  EXPECT_EQ(rep.non_manifold_edge_count, 0);
}

TEST(MeshRefine, NothingToDoAndBadLimit) {
  const Mesh tet = make_tetrahedron();
  const Mesh r = refine_mesh(tet, 10.0);
  EXPECT_TRUE(r.vertices == tet.vertices);
  EXPECT_TRUE(r.triangles == tet.triangles);
  EXPECT_THROW(refine_mesh(tet, 0.0), std::invalid_argument);
  EXPECT_THROW(refine_mesh(tet, std::nan("")), std::invalid_argument);
}

// A board 0.3 x 0.2 x 0.01 m refined to 2 cm edges. Every pair joins a vertex to its mirror
// image on the other face, 1 cm behind it, and every vertex inside the faces (off the rim) is
// paired exactly once. On the rim (the thin sides, refined into slivers) vertices may or may
// not be paired depending on how their normals lean.
TEST(MeshLayers, BoardFacesArePairedVertexToVertex) {
  const Mesh board = refine_mesh(make_box_mesh(0.3, 0.2, 0.01), 0.02);
  const auto pairs = opposite_layer_pairs(board.vertices, board.triangles, 0.015);
  std::vector<int> partners(static_cast<size_t>(board.num_vertices()), 0);
  for (const auto& [a, b] : pairs) {
    EXPECT_LT(a, b);
    const Eigen::RowVector3d d = board.vertices.row(b) - board.vertices.row(a);
    EXPECT_NEAR(std::abs(d.z()), 0.01, 1e-12) << a << "-" << b;
    EXPECT_NEAR(d.head<2>().norm(), 0.0, 1e-12) << a << "-" << b;
    ++partners[static_cast<size_t>(a)];
    ++partners[static_cast<size_t>(b)];
  }
  int inside = 0;
  for (int i = 0; i < board.num_vertices(); ++i) {
    const auto v = board.vertices.row(i);
    if (std::abs(v.x()) > 0.15 - 1e-9 || v.y() < 1e-9 || v.y() > 0.2 - 1e-9) continue;
    ++inside;
    EXPECT_EQ(partners[static_cast<size_t>(i)], 1) << "vertex " << i << " at " << v;
  }
  EXPECT_GT(inside, 100);
  // Reach shorter than the thickness: no pairs.
  EXPECT_TRUE(opposite_layer_pairs(board.vertices, board.triangles, 0.009).empty());
  EXPECT_THROW(opposite_layer_pairs(board.vertices, board.triangles, 0.0), std::invalid_argument);
}

// A sphere has no opposite layer within a tenth of its radius.
TEST(MeshLayers, ThickClosedSurfaceHasNoPairs) {
  const Mesh ball = make_icosphere(0.1, 3);
  EXPECT_TRUE(opposite_layer_pairs(ball.vertices, ball.triangles, 0.01).empty());
}

// The mean length of the mesh's undirected edges, computed here on its own.
double mean_edge(const Mesh& m) {
  std::set<std::pair<int, int>> edges;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f)
    for (int k = 0; k < 3; ++k) {
      const int a = m.triangles(f, k), b = m.triangles(f, (k + 1) % 3);
      edges.emplace(std::min(a, b), std::max(a, b));
    }
  double total = 0.0;
  for (const auto& [a, b] : edges) total += (m.vertices.row(b) - m.vertices.row(a)).norm();
  return total / static_cast<double>(edges.size());
}

// A board 1 cm thick meshed coarser than its thickness: its layers are within the mean edge,
// which is the default reach, as before.
TEST(MeshLayers, DefaultReachIsTheMeanEdgeWhereItFindsTheLayers) {
  const Mesh board = refine_mesh(make_box_mesh(0.4, 0.3, 0.01), 0.05);
  const double mean = mean_edge(board);
  ASSERT_GT(mean, 0.01);
  EXPECT_NEAR(default_layer_reach(board.vertices, board.triangles), mean, 1e-12 * mean);
}

// No facing pair of `board` (1 cm thick) lies within its mean edge; the default reach is the
// first doubling of the mean edge at which one does, and the board then splits into one sheet.
void expect_layers_found_by_doubling(const Mesh& board) {
  const double mean = mean_edge(board);
  ASSERT_TRUE(opposite_layer_pairs(board.vertices, board.triangles, mean).empty());
  const double reach = default_layer_reach(board.vertices, board.triangles);
  EXPECT_GE(reach, 0.01);
  const double doublings = std::log2(reach / mean);
  EXPECT_NEAR(doublings, std::round(doublings), 1e-9);
  EXPECT_TRUE(opposite_layer_pairs(board.vertices, board.triangles, reach / 2).empty());
  EXPECT_FALSE(opposite_layer_pairs(board.vertices, board.triangles, reach).empty());
  EXPECT_TRUE(make_thin_sheet(board.vertices, board.triangles, reach).has_value());
}

// The same board meshed finer than its thickness (mean edge about 5 mm): its layers are not
// within a mean edge (no sheet there) but within a doubling of it.
TEST(MeshLayers, DefaultReachFindsTheLayersOfAFinelyMeshedBoard) {
  const Mesh board = refine_mesh(make_box_mesh(0.4, 0.3, 0.01), 0.007);
  ASSERT_LT(mean_edge(board), 0.01);
  expect_layers_found_by_doubling(board);
  EXPECT_FALSE(make_thin_sheet(board.vertices, board.triangles, mean_edge(board)).has_value());
}

// The fine board bent into a half cylinder, faces still 1 cm apart: a thin closed body too
// (its mean thickness, 2 V / A, is about 1 cm), so its layers are found as on the flat board.
TEST(MeshLayers, DefaultReachFindsTheLayersOfABentBoard) {
  Mesh board = refine_mesh(make_box_mesh(0.4, 0.3, 0.01), 0.007);
  board.vertices = test::bent_about_y(board.vertices, 0.4 / 3.14159265358979);
  expect_layers_found_by_doubling(board);
}

// Nothing faces across a ball within 5% of its bounding box's diagonal (0.017 m against a
// diameter of 0.2 m), nor across an open sheet: the reach stays the mean edge. A mesh without
// triangles has none.
TEST(MeshLayers, DefaultReachStaysTheMeanEdgeWithoutLayers) {
  const Mesh ball = make_icosphere(0.1, 3);
  EXPECT_NEAR(default_layer_reach(ball.vertices, ball.triangles), mean_edge(ball),
              1e-12 * mean_edge(ball));
  Mesh sheet;  // 0.3 x 0.2 m, 12 x 8 cells
  sheet.vertices.resize(13 * 9, 3);
  sheet.triangles.resize(2 * 12 * 8, 3);
  for (int j = 0; j <= 8; ++j)
    for (int i = 0; i <= 12; ++i) sheet.vertices.row(j * 13 + i) << 0.025 * i, 0.025 * j, 0.0;
  for (int j = 0, f = 0; j < 8; ++j)
    for (int i = 0; i < 12; ++i) {
      const int v = j * 13 + i;
      sheet.triangles.row(f++) << v, v + 1, v + 14;
      sheet.triangles.row(f++) << v, v + 14, v + 13;
    }
  EXPECT_NEAR(default_layer_reach(sheet.vertices, sheet.triangles), mean_edge(sheet),
              1e-12 * mean_edge(sheet));
  EXPECT_EQ(default_layer_reach(ball.vertices, Triangles(0, 3)), 0.0);
}

}  // namespace
}  // namespace pbve
