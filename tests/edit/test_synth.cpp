// The synthetic shapes: their sizes and the arguments that make no closed surface.

#include "pbve/edit/synth.hpp"

#include <cmath>
#include <exception>
#include <string>
#include <utility>

#include <gtest/gtest.h>

#include "pbve/core/error.hpp"
#include "pbve/core/mesh.hpp"

namespace pbve {
namespace {

// rings - 1 rings of `segments` vertices between two poles.
TEST(Figurine, VertexAndTriangleCountsFollowRingsAndSegments) {
  for (const auto& [rings, segments] : {std::pair{2, 3}, std::pair{3, 4}, std::pair{48, 48}}) {
    const Mesh m = make_figurine(0.36, rings, segments);
    EXPECT_EQ(m.num_vertices(), 2 + (rings - 1) * segments) << rings << " " << segments;
    EXPECT_EQ(m.num_triangles(), 2 * (rings - 1) * segments) << rings << " " << segments;
    EXPECT_GT(enclosed_volume(m.vertices, m.triangles), 0.0) << rings << " " << segments;
  }
}

// Below 2 rings the triangles indexed vertices that were never made (an error from
// enclosed_volume() that named neither the function nor the argument); below 3 segments the
// mesh was flat (1 or 2) or had no triangle at all (0 or less).
TEST(Figurine, TooFewRingsOrSegmentsNameTheArgument) {
  const auto message = [](int rings, int segments) -> std::string {
    try {
      make_figurine(0.36, rings, segments);
    } catch (const InputError& e) {
      return e.what();
    } catch (const std::exception& e) {
      return std::string("another exception: ") + e.what();
    }
    return "accepted";
  };
  for (const int rings : {1, 0, -5})
    EXPECT_EQ(message(rings, 48),
              "make_figurine: rings must be at least 2, got " + std::to_string(rings));
  for (const int segments : {2, 1, 0, -1})
    EXPECT_EQ(message(48, segments),
              "make_figurine: segments must be at least 3, got " + std::to_string(segments));
}

// A height that is not positive and finite made a point, a mirrored figurine or NaN vertices
// without a word; a ring and segment count beyond int's vertex indices overflowed them.
TEST(Figurine, HeightAndSizeOutOfRangeNameTheArgument) {
  const auto message = [](double height, int rings, int segments) -> std::string {
    try {
      make_figurine(height, rings, segments);
    } catch (const InputError& e) {
      return e.what();
    } catch (const std::exception& e) {
      return std::string("another exception: ") + e.what();
    }
    return "accepted";
  };
  for (const double height : {0.0, -0.36, std::nan(""), HUGE_VAL})
    EXPECT_EQ(
        message(height, 8, 8).rfind("make_figurine: height must be positive and finite, got ", 0),
        0u)
        << height;
  EXPECT_EQ(message(0.36, 65536, 65536),
            "make_figurine: rings 65536 x segments 65536 make more vertices and triangles than int "
            "indices hold");
  EXPECT_EQ(message(0.36, 8, 8), "accepted");
}

}  // namespace
}  // namespace pbve
