#pragma once
/// @file
/// The per-run report (JSON): per-frame metrics, a summary with faithfulness warnings, and the
/// resolved settings. The format is in docs/formats.md ("Report (JSON)").

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace pbve {

/// One output frame.
struct FrameRecord {
  int index = 0;                 ///< output frame index (input frame numbering)
  double violation_pct = 0.0;    ///< % of the object's pixels showing unobserved triangles
  double visible_area_px = 0.0;  ///< object pixels in the output frame
  double control_force = 0.0;    ///< sum of control force norms, N
  double physical_force = 0.0;   ///< sum of the other force norms on free vertices, N
  double solve_ms = 0.0;         ///< optimizer time for this frame
  double frame_ms = 0.0;         ///< whole frame (simulate, optimize, render, write)
  int iterations = 0;            ///< optimizer iterations
  std::string status;            ///< optimizer status ("converged", "off", ...)
  bool pose_lost = false;        ///< the input pose of this frame was `lost`
  /// Multiple of the scene's substeps this frame was simulated with: 1, or 2 / 4 when the
  /// simulation diverged at the scene's substeps and the frame was recomputed.
  int substep_factor = 1;
};

/// Summary over the frames. A figure that is NaN (unknown: null in the JSON) is left out of
/// the statistics of that figure, and its frame counted in nan_frames; a statistic no frame
/// has a number for is NaN (the ratio median: 0). Infinite figures are kept.
struct ReportSummary {
  int frames = 0;
  double violation_pct_mean = 0.0;
  double violation_pct_max = 0.0;
  /// Median over frames with a non-zero physical force of control_force / physical_force,
  /// where that ratio is a number (a NaN force, or both forces infinite, leaves the frame out);
  /// 0 when no frame has one.
  double control_to_physical_force_median = 0.0;
  double ms_per_frame_mean = 0.0;
  double solve_ms_mean = 0.0;
  /// Frames with a figure of the summary's (violation_pct, control_force, physical_force,
  /// frame_ms, solve_ms) that is NaN.
  int nan_frames = 0;
};

/// Tracking run before editing (scene key `object.poses: track`).
struct ReportTracking {
  std::filesystem::path poses;  ///< the tracked pose file written
  std::vector<int> lost;        ///< frames whose pose is `lost`
  double ms_per_frame = 0.0;    ///< tracking time per frame
  int left_view_at = -1;        ///< first frame of a final lost run out of view, or -1
};

/// A whole report.
struct Report {
  std::vector<FrameRecord> frames;
  std::vector<std::string> warnings;
  /// The resolved scene (scene_to_yaml()); written as JSON (as a string when it is not YAML).
  std::string settings_yaml;
  bool complete = true;  ///< false when the run stopped early (see stopped_reason)
  int stopped_at = -1;   ///< when incomplete: the first input frame not edited
  std::string stopped_reason;
  std::string engine;                      ///< simulator name
  std::optional<ReportTracking> tracking;  ///< when the poses were tracked first

  ReportSummary summary() const;
};

/// Warnings about faithfulness (paper section 4.6): runs of frames where the control force
/// exceeds `ratio` times the physical force, e.g. "control forces exceed 25% of physical
/// forces in frames 40-52: the requested physics is not faithfully reproduced".
std::vector<std::string> faithfulness_warnings(const std::vector<FrameRecord>& frames,
                                               double ratio = 0.25);

/// Writes the report as JSON through a temporary name renamed on success. JSON text is UTF-8:
/// in a string that is not (a file name in Latin-1, say), each byte that is not part of a
/// valid UTF-8 sequence is written as U+FFFD, the replacement character (JSON and its library
/// have no lossless escape for a raw byte); the rest of the string is kept.
void write_report(const Report& report, const std::filesystem::path& path);
/// Reads a report written by write_report(). Throws InputError naming the file.
Report read_report(const std::filesystem::path& path);

}  // namespace pbve
