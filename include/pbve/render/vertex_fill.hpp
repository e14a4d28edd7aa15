#pragma once
/// @file
/// Fail-safe colour fill over the mesh graph: per-vertex colours known on the observed part of
/// the surface are propagated to the vertices of unobserved triangles (the paper's "linearly
/// interpolate the texture from the neighbourhood triangles", section 3.3).

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "pbve/core/mesh.hpp"

namespace pbve {

/// The vertex graph of a triangle mesh (vertices sharing an edge are neighbours), in
/// compressed-row form: the neighbours of vertex i are neighbours[offsets[i] .. offsets[i+1]).
struct VertexGraph {
  std::vector<int> offsets;     ///< #V + 1
  std::vector<int> neighbours;  ///< 2 #E, sorted per vertex

  int num_vertices() const { return offsets.empty() ? 0 : static_cast<int>(offsets.size()) - 1; }
  /// Builds the graph of `triangles` over `num_vertices` vertices.
  static VertexGraph from_triangles(const Triangles& triangles, int num_vertices);
};

/// Fills the colours of the vertices with known[i] == 0 from those with known[i] != 0.
///
/// First a front propagation: the unknown vertices at graph distance d from the known set take
/// the mean colour of their neighbours at distance d - 1 (d = 1, 2, ...). Then
/// `smoothing_sweeps` Gauss-Seidel sweeps of the graph Laplacian over the unknown vertices only
/// (known colours stay fixed), which moves the fill towards the harmonic interpolant of the
/// known boundary colours (linear along a chain). Vertices with no path to a known vertex get
/// `fallback`.
///
/// @param graph             the vertex graph, #V vertices
/// @param colors            #V colours (any units, e.g. BGR 0..255); unknown entries are
///                          overwritten, known ones are left unchanged
/// @param known             #V flags
/// @param smoothing_sweeps  >= 0
/// @param fallback          colour of vertices cut off from every known vertex
/// @return the number of vertices that were filled (known[i] == 0)
int fill_vertex_colors(const VertexGraph& graph, std::vector<cv::Vec3f>& colors,
                       const std::vector<std::uint8_t>& known, int smoothing_sweeps,
                       const cv::Vec3f& fallback);

}  // namespace pbve
