#pragma once
/// @file
/// The editor: the per-frame driver from a scene to the edited video and its report.
///
/// Per frame t (paper sections 3.2-3.4 and 4.1): the simulator starts at rest in the first
/// frame's aligned pose; the anchors follow the input poses; the triangles not observed in
/// input frame t (back-facing or hidden, by ray casting) must stay hidden, and the control
/// optimizer adds the forces that keep them so; the simulated mesh is textured from input
/// frame t, composited over the background plate, written, and measured (violation_pct).

#include <atomic>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>

#include "pbve/edit/engine_recipe.hpp"
#include "pbve/edit/report.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/sim/simulator.hpp"

namespace pbve {

/// Overrides of the scene for one run (the command line's options).
struct EditOptions {
  std::filesystem::path video;  ///< output video; empty = the scene's output.video
  /// report; empty = the scene's output.report, or, when the scene gives none, the name of the
  /// video written with .json
  std::filesystem::path report;
  std::optional<bool> control;  ///< force control on or off (--no-control)
  int first_frame = 0;          ///< first input frame to edit (--frames A:B)
  int end_frame = -1;           ///< one past the last input frame; -1 = all
};

/// Progress of a run, reported after every frame.
struct EditProgress {
  int frame = 0;       ///< frames done
  int total = 0;       ///< frames to do
  FrameRecord record;  ///< the frame just finished
};

/// Hooks for long runs.
struct EditCallbacks {
  std::function<void(const EditProgress&)> progress;
  /// Polled between frames and inside the optimizer: true = stop after the current frame,
  /// close the video validly and write the report marked incomplete. Polled between tracked
  /// frames too (`poses: track`): true there throws EditCancelled, nothing written.
  std::function<bool()> cancel;
  /// Creates the simulator (required): pbve::make_engine() from pbve/engines.hpp for the
  /// built-in engines, or a factory of one's own adapter. It throws InputError for an engine
  /// or settings it does not take; a null pointer is an InputError at `simulation.engine`.
  std::function<std::unique_ptr<Simulator>(const EngineRecipe&)> make_simulator;
};

/// Thrown by run_edit() when the cancel hook stops it before the first edited frame (while
/// tracking): no output is written.
class EditCancelled : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// How a run ended.
enum class EditStatus {
  completed,  ///< every frame was edited
  cancelled,  ///< the cancel hook stopped it after a frame
  diverged,   ///< the simulation diverged in a frame even with 4x the substeps
};

/// What a run produced. When the run stopped early (cancelled or diverged) the video holds
/// the frames edited so far and the report is marked incomplete (Report::complete,
/// Report::stopped_at, Report::stopped_reason); both are still written.
struct EditResult {
  Report report;
  std::filesystem::path video;
  std::filesystem::path report_path;
  bool complete = true;  ///< status == EditStatus::completed
  EditStatus status = EditStatus::completed;
};

/// Runs the whole edit: reads the scene's inputs, simulates, controls, renders, writes the
/// video and the report (each through a temporary name renamed when complete). Throws
/// InputError for bad input (before any output is written) with the file, line or key at
/// fault; refuses to write over an input file. An exception leaves no output file (nor a
/// temporary one) behind.
///
/// Runtime faults: a frame whose simulation diverges (non-finite or runaway positions, or the
/// engine throws) is recomputed with 2x, then 4x the substeps (recorded per frame in
/// FrameRecord::substep_factor, with a warning); if that fails too the run stops there with
/// EditStatus::diverged. When the control optimizer fails (throws, or returns non-finite
/// forces or energy) the frame is simulated without control forces, with a warning.
EditResult run_edit(const Scene& scene, const EditOptions& options, const EditCallbacks& callbacks);

}  // namespace pbve
