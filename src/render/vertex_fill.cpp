#include "pbve/render/vertex_fill.hpp"

#include <algorithm>
#include <string>

#include "pbve/core/error.hpp"

namespace pbve {

VertexGraph VertexGraph::from_triangles(const Triangles& triangles, int num_vertices) {
  VertexGraph graph;
  graph.offsets.assign(static_cast<size_t>(num_vertices) + 1, 0);
  // Directed edge list (both directions of every triangle edge), then sorted and deduplicated
  // per vertex.
  std::vector<std::pair<int, int>> edges;
  edges.reserve(static_cast<size_t>(triangles.rows()) * 6);
  for (Eigen::Index j = 0; j < triangles.rows(); ++j) {
    for (int k = 0; k < 3; ++k) {
      const int a = triangles(j, k), b = triangles(j, (k + 1) % 3);
      if (a < 0 || b < 0 || a >= num_vertices || b >= num_vertices)
        throw InputError("vertex index out of range [0, " + std::to_string(num_vertices) + ")", {},
                         0, "triangle " + std::to_string(j));
      if (a == b) continue;
      edges.emplace_back(a, b);
      edges.emplace_back(b, a);
    }
  }
  std::sort(edges.begin(), edges.end());
  edges.erase(std::unique(edges.begin(), edges.end()), edges.end());
  graph.neighbours.resize(edges.size());
  for (size_t e = 0; e < edges.size(); ++e) {
    graph.neighbours[e] = edges[e].second;
    ++graph.offsets[static_cast<size_t>(edges[e].first) + 1];
  }
  for (int i = 0; i < num_vertices; ++i) graph.offsets[i + 1] += graph.offsets[i];
  return graph;
}

int fill_vertex_colors(const VertexGraph& graph, std::vector<cv::Vec3f>& colors,
                       const std::vector<std::uint8_t>& known, int smoothing_sweeps,
                       const cv::Vec3f& fallback) {
  const int n = graph.num_vertices();
  if (static_cast<int>(colors.size()) != n || static_cast<int>(known.size()) != n)
    throw InputError("fill_vertex_colors(): the graph has " + std::to_string(n) +
                     " vertices, got " + std::to_string(colors.size()) + " colours and " +
                     std::to_string(known.size()) + " flags");
  // Front propagation in rings: level[i] = graph distance to the known set (-1 = not reached).
  std::vector<int> level(static_cast<size_t>(n), -1);
  std::vector<int> order;  // unknown vertices in the order they are reached
  std::vector<int> front, next;
  for (int i = 0; i < n; ++i)
    if (known[i]) {
      level[i] = 0;
      front.push_back(i);
    }
  int filled = 0;
  for (int d = 1; !front.empty(); ++d) {
    next.clear();
    for (int i : front)
      for (int e = graph.offsets[i]; e < graph.offsets[i + 1]; ++e) {
        const int k = graph.neighbours[e];
        if (level[k] < 0) {
          level[k] = d;
          next.push_back(k);
        }
      }
    for (int k : next) {
      cv::Vec3f sum(0, 0, 0);
      int count = 0;
      for (int e = graph.offsets[k]; e < graph.offsets[k + 1]; ++e) {
        const int m = graph.neighbours[e];
        if (level[m] == d - 1) {
          sum += colors[m];
          ++count;
        }
      }
      colors[k] = sum * (1.0f / static_cast<float>(count));
      order.push_back(k);
    }
    filled += static_cast<int>(next.size());
    std::swap(front, next);
  }
  // Laplacian smoothing of the filled values (known vertices are the fixed boundary).
  for (int sweep = 0; sweep < smoothing_sweeps; ++sweep) {
    for (int k : order) {
      cv::Vec3f sum(0, 0, 0);
      const int begin = graph.offsets[k], end = graph.offsets[k + 1];
      for (int e = begin; e < end; ++e) sum += colors[graph.neighbours[e]];
      colors[k] = sum * (1.0f / static_cast<float>(end - begin));
    }
  }
  for (int i = 0; i < n; ++i)
    if (level[i] < 0) {
      colors[i] = fallback;
      ++filled;
    }
  return filled;
}

}  // namespace pbve
