// pbve edit: scene file -> edited video + report.

#include <unistd.h>

#include <charconv>
#include <cstdio>
#include <string>

#include "cli/commands.hpp"
#include "pbve/edit/editor.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/engines.hpp"

namespace pbve::cli {

namespace {

void parse_frames(const std::string& spec, EditOptions& o) {
  const auto colon = spec.find(':');
  if (colon == std::string::npos) throw UsageError("--frames expects A:B, got '" + spec + "'");
  // Whole non-negative integers only ("1x" is no frame number).
  auto number = [&](const std::string& text, int fallback) {
    if (text.empty()) return fallback;
    int v = 0;
    const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), v);
    if (ec != std::errc() || end != text.data() + text.size())
      throw UsageError("--frames expects A:B with whole numbers, got '" + spec + "'");
    if (v < 0) throw UsageError("--frames " + spec + ": frame numbers start at 0");
    return v;
  };
  o.first_frame = number(spec.substr(0, colon), 0);
  o.end_frame = number(spec.substr(colon + 1), -1);
  if (o.end_frame >= 0 && o.end_frame <= o.first_frame)
    throw UsageError("--frames " + spec + " is an empty range");
}

void print_progress(const EditProgress& p, bool tty) {
  const FrameRecord& r = p.record;
  if (tty) {
    const int width = 30;
    const int filled = p.total > 0 ? width * p.frame / p.total : width;
    std::fprintf(stderr, "\r[%.*s%*s] %d/%d  frame %d  violation %5.2f%%  %6.1f ms/frame", filled,
                 "##############################", width - filled, "", p.frame, p.total, r.index,
                 r.violation_pct, r.frame_ms);
    if (p.frame == p.total) std::fputc('\n', stderr);
  } else {
    std::fprintf(
        stderr, "frame %d (%d/%d): violation %.2f%%, control %.4g N, physical %.4g N, %.1f ms\n",
        r.index, p.frame, p.total, r.violation_pct, r.control_force, r.physical_force, r.frame_ms);
  }
  std::fflush(stderr);
}

}  // namespace

int run_edit(const std::vector<std::string>& argv) {
  Args args(argv);
  if (args.help()) {
    std::puts(
        "usage: pbve edit SCENE.yaml [-o OUT.mp4] [--report R.json] [--no-control | --control]\n"
        "                 [--frames A:B] [--quiet]\n"
        "\n"
        "Simulates the scene's object with its new physics, optimizes control forces that keep\n"
        "the parts whose texture is unknown turned away from the camera, textures the simulated\n"
        "object from the footage, composites it over the background plate, and writes the edited\n"
        "video and a JSON report. Outputs are written under a temporary name and renamed when\n"
        "complete; Ctrl-C or SIGTERM finishes the current frame and writes a valid, shorter\n"
        "video and a report marked incomplete (while tracking, `poses: track`, they stop with\n"
        "nothing written).\n"
        "\n"
        "options:\n"
        "  -o, --output OUT   edited video (default: the scene's output.video)\n"
        "  --report R.json    report (default: the scene's output.report, else the video's name\n"
        "                     with .json)\n"
        "  --no-control       the unconstrained baseline: no control forces\n"
        "  --control          force control on even if the scene disables it\n"
        "  --frames A:B       edit input frames A (inclusive) to B (exclusive); either may be "
        "empty\n"
        "  --quiet            no progress output\n"
        "\n"
        "exit status: 0 when the video and the report were written, 1 on error, 2 on bad usage,\n"
        "130 when interrupted (the partial results are still written, unless interrupted while\n"
        "tracking). A frame whose simulation\n"
        "diverges is recomputed with 2x then 4x the substeps; if it still diverges the run stops\n"
        "with status 1, keeping the frames edited so far (report marked incomplete).");
    return 0;
  }
  EditOptions o;
  o.video = args.value("--output", "-o");
  o.report = args.value("--report");
  const bool no_control = args.flag("--no-control"), control = args.flag("--control");
  if (no_control && control) throw UsageError("--no-control and --control exclude each other");
  if (no_control) o.control = false;
  if (control) o.control = true;
  const std::string frames = args.value("--frames");
  if (!frames.empty()) parse_frames(frames, o);
  const bool quiet = args.flag("--quiet");
  const auto pos = args.positional();
  if (pos.size() != 1) throw UsageError("expected one scene file");

  const Scene scene = load_scene(pos[0]);
  check_engine(scene);
  const bool tty = ::isatty(STDERR_FILENO) != 0;
  EditCallbacks cb;
  cb.make_simulator = [](const EngineRecipe& r) { return make_engine(r); };
  if (!quiet) cb.progress = [tty](const EditProgress& p) { print_progress(p, tty); };
  cb.cancel = [] { return interrupted(); };
  EditResult r;
  try {
    const InterruptGuard guard;
    r = run_edit(scene, o, cb);
  } catch (const EditCancelled& e) {
    throw Interrupted(e.what());
  }
  const ReportSummary s = r.report.summary();
  std::printf("edited video: %s\nreport:       %s\n", r.video.c_str(), r.report_path.c_str());
  if (r.report.tracking)
    std::printf("tracked poses: %s (%zu frames lost, %.1f ms per frame)\n",
                r.report.tracking->poses.c_str(), r.report.tracking->lost.size(),
                r.report.tracking->ms_per_frame);
  std::printf(
      "frames %d, violation mean %.3f%% max %.3f%%, control/physical force median %.3f, "
      "%.1f ms/frame\n",
      s.frames, s.violation_pct_mean, s.violation_pct_max, s.control_to_physical_force_median,
      s.ms_per_frame_mean);
  if (s.nan_frames > 0)
    std::printf("%d frames with unknown (NaN) figures, left out of those statistics\n",
                s.nan_frames);
  for (const auto& w : r.report.warnings) std::printf("warning: %s\n", w.c_str());
  if (r.status == EditStatus::diverged) {
    std::fflush(stdout);
    std::fprintf(stderr, "pbve edit: error: %s (the video and the report hold frames %d to %d)\n",
                 r.report.stopped_reason.c_str(), o.first_frame, r.report.stopped_at - 1);
    return 1;
  }
  if (!r.complete) {
    std::printf("stopped early: %s\n", r.report.stopped_reason.c_str());
    return 130;
  }
  return 0;
}

}  // namespace pbve::cli
