// pbve track: footage + mesh + intrinsics + initial pose -> pose file (+ overlay video).

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <opencv2/imgproc.hpp>

#include "cli/commands.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/core/pose.hpp"
#include "pbve/track/tracker.hpp"

namespace pbve::cli {

namespace {

Camera parse_camera(const std::string& spec) {
  std::vector<double> v;
  std::stringstream ss(spec);
  std::string item;
  while (std::getline(ss, item, ',')) {
    try {
      size_t used = 0;
      v.push_back(std::stod(item, &used));
      if (used != item.size()) throw std::invalid_argument(item);
    } catch (const std::exception&) {
      throw UsageError("--camera expects fx,fy,cx,cy (pixels), got '" + spec + "'");
    }
  }
  if (v.size() != 4) throw UsageError("--camera expects fx,fy,cx,cy (pixels), got '" + spec + "'");
  Camera c;
  c.fx = v[0];
  c.fy = v[1];
  c.cx = v[2];
  c.cy = v[3];
  return c;
}

}  // namespace

int run_track(const std::vector<std::string>& argv) {
  Args args(argv);
  if (args.help()) {
    std::puts(
        "usage: pbve track VIDEO MESH --camera fx,fy,cx,cy (--initial-pose POSES.txt |\n"
        "                  --correspondences PAIRS.txt) -o POSES.txt [--overlay OVERLAY.mp4]\n"
        "                  [--truth TRUE_POSES.txt] [--log LOG.csv] [--quiet]\n"
        "\n"
        "Estimates the pose of the object (MESH, OBJ or PLY) in every frame of VIDEO from a\n"
        "static camera, starting from its pose in the first frame, and writes a pose file (one\n"
        "line per frame, `lost` where tracking could not be trusted) for `pbve edit`.\n"
        "\n"
        "options:\n"
        "  --camera fx,fy,cx,cy      intrinsics in pixels (the image size comes from VIDEO)\n"
        "  --initial-pose FILE       a pose file whose first pose is the object's in frame 0\n"
        "  --correspondences FILE    at least 4 lines 'VERTEX u v' (mesh vertex index, pixel) or\n"
        "                            'x y z u v' (mesh point, pixel) in frame 0, solved by PnP\n"
        "  -o, --output FILE         the pose file to write\n"
        "  --overlay FILE            a video of the footage with the mesh's projected silhouette\n"
        "                            and crease edges (green; red text where lost)\n"
        "  --truth FILE              true poses (e.g. from pbve synth): prints the reprojection\n"
        "                            error per frame (mean over vertices): median and maximum\n"
        "  --log FILE                per-frame table (CSV): lost, corners, inliers, RMS, "
        "silhouette\n"
        "                            agreement, keyframe, re-detection, error against --truth\n"
        "  --quiet                   no progress output\n"
        "\n"
        "exit status: 0 on success, 1 on error or when the object left the view for good (the\n"
        "pose file is still written, `lost` from there), 2 on bad usage, 130 when interrupted\n"
        "(Ctrl-C or SIGTERM: nothing written).");
    return 0;
  }
  const std::string camera_spec = args.value("--camera");
  const std::string initial = args.value("--initial-pose");
  const std::string pairs = args.value("--correspondences");
  const std::string output = args.value("--output", "-o");
  const std::string overlay = args.value("--overlay");
  const std::string truth = args.value("--truth");
  const std::string log = args.value("--log");
  const bool quiet = args.flag("--quiet");
  const auto pos = args.positional();
  if (pos.size() != 2) throw UsageError("expected VIDEO and MESH");
  if (camera_spec.empty()) throw UsageError("--camera fx,fy,cx,cy is required");
  if (output.empty()) throw UsageError("-o POSES.txt is required");
  if (initial.empty() && pairs.empty())
    throw UsageError(
        "the initial pose is missing: give --initial-pose FILE or --correspondences FILE");
  if (!initial.empty() && !pairs.empty())
    throw UsageError("--initial-pose and --correspondences exclude each other: give one");
  // Outputs: not an input (through any link or spelling), not each other, and writable, before
  // any work; refused with status 1, as `pbve edit` refuses its outputs.
  const std::vector<std::string> outputs = {output, overlay, log};
  for (size_t i = 0; i < outputs.size(); ++i) {
    if (outputs[i].empty()) continue;
    for (const auto& in : {pos[0], pos[1], initial, pairs, truth})
      if (same_file(outputs[i], in))
        throw InputError("the output would overwrite the input " + in, outputs[i]);
    for (size_t j = 0; j < i; ++j)
      if (same_file(outputs[i], outputs[j]))
        throw InputError("two outputs are the same file: " + outputs[j] + " and " + outputs[i]);
    check_writable(outputs[i]);
  }

  Footage footage = Footage::open_video(pos[0]);
  const Mesh mesh = load_mesh(pos[1]);
  validate_mesh(mesh, pos[1]);
  Camera camera = parse_camera(camera_spec);
  const cv::Mat first = footage.frame(0);
  camera.width = first.cols;
  camera.height = first.rows;
  camera.validate();

  Pose start;
  if (!initial.empty()) {
    const PoseTrack t = load_pose_file(initial);
    if (t.size() == 0 || !t.poses[0])
      throw InputError("the first line must be a pose (not `lost`) for frame 0", initial, 1);
    start = *t.poses[0];
  } else {
    start = pose_from_correspondence_file(pairs, mesh, camera);
  }
  PoseTrack true_track;
  if (!truth.empty()) true_track = load_pose_file(truth);

  const InterruptGuard guard;  // before the overlay's temporary file exists
  std::unique_ptr<VideoWriter> writer;
  if (!overlay.empty())
    writer = std::make_unique<VideoWriter>(overlay, footage.fps(),
                                           cv::Size(camera.width, camera.height));
  const bool tty = ::isatty(STDERR_FILENO) != 0;
  const int n = footage.frame_count();
  std::vector<double> errors;
  std::ostringstream table;
  table << "frame,lost,correspondences,inliers,rms_px,agreement,keyframe,redetected,error_px\n";
  TrackFrameCallback on_frame = [&](int t, const cv::Mat& frame, const std::optional<Pose>& pose,
                                    const TrackFrameInfo& info) {
    if (interrupted())
      throw Interrupted("interrupted at frame " + std::to_string(t) + ": nothing written");
    if (writer) {
      cv::Mat out = frame.clone();
      if (pose) draw_mesh_edges(out, mesh, camera, *pose);
      if (!pose)
        cv::putText(out, "lost", cv::Point(10, 30), cv::FONT_HERSHEY_SIMPLEX, 0.9,
                    cv::Scalar(0, 0, 255), 2);
      writer->write(out);
    }
    const bool have_truth = t < true_track.size() && true_track.poses[static_cast<size_t>(t)];
    if (have_truth)
      errors.push_back(pose ? reprojection_error_px(mesh, camera, *pose,
                                                    *true_track.poses[static_cast<size_t>(t)])
                            : std::numeric_limits<double>::infinity());
    char row[256];
    std::snprintf(row, sizeof row, "%d,%d,%d,%d,%.3f,%.3f,%d,%d,", t, info.lost ? 1 : 0,
                  info.correspondences, info.inliers, info.rms_px, info.agreement,
                  info.new_keyframe ? 1 : 0, info.relocalized ? 1 : 0);
    table << row;
    if (have_truth) table << (pose ? std::to_string(errors.back()) : std::string("inf"));
    table << "\n";
    if (!quiet) {
      if (tty)
        std::fprintf(stderr, "\rframe %d/%d  %s  inliers %d   ", t + 1, n,
                     info.lost ? "lost   " : "tracked", info.inliers);
      else if (info.lost || (t + 1) % 30 == 0 || t + 1 == n)
        std::fprintf(stderr, "frame %d/%d: %s, %d inliers of %d\n", t + 1, n,
                     info.lost ? "lost" : "tracked", info.inliers, info.correspondences);
    }
  };
  const TrackResult r = track_footage(footage, mesh, camera, start, TrackOptions{}, on_frame);
  if (!quiet && tty) std::fputc('\n', stderr);
  save_pose_file(r.track, output);
  if (!log.empty())
    write_atomically(log, [&](const std::filesystem::path& tmp) {
      std::ofstream f(tmp);
      f << table.str();
      if (!f) throw InputError("cannot write the log", log);
    });
  if (writer) writer->close();

  std::printf("poses:   %s (%d frames, %d lost)\n", output.c_str(), r.track.size(),
              r.track.lost_count());
  if (writer) std::printf("overlay: %s\n", overlay.c_str());
  std::printf("tracking %.1f ms per frame (%.0f frames per second, decoding excluded)\n",
              r.track_ms_per_frame, r.track_ms_per_frame > 0 ? 1000.0 / r.track_ms_per_frame : 0.0);
  if (!errors.empty()) {
    std::vector<double> sorted = errors;
    std::sort(sorted.begin(), sorted.end());
    const auto worst = std::max_element(errors.begin(), errors.end());
    std::printf(
        "reprojection error against %s over %zu frames: median %.3f px, max %.3f px (frame "
        "%td), %zu frames above 5 px\n",
        truth.c_str(), errors.size(), sorted[sorted.size() / 2], *worst, worst - errors.begin(),
        static_cast<size_t>(
            std::count_if(errors.begin(), errors.end(), [](double e) { return e > 5.0; })));
  }
  if (r.left_view_at >= 0) {
    std::fflush(stdout);
    std::fprintf(stderr,
                 "pbve track: error: the object left the view at frame %d and was not found "
                 "again: frames %d to %d are `lost` in %s\n",
                 r.left_view_at, r.left_view_at, n - 1, output.c_str());
    return 1;
  }
  return 0;
}

}  // namespace pbve::cli
