// pbve synth and pbve plot.

#include <cmath>
#include <cstdio>
#include <filesystem>

#include <opencv2/imgcodecs.hpp>

#include "cli/commands.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/footage.hpp"
#include "pbve/edit/plot.hpp"
#include "pbve/edit/synth.hpp"

namespace pbve::cli {

namespace fs = std::filesystem;

namespace {

int parse_int(const std::string& s, const char* what) {
  try {
    size_t n = 0;
    const int v = std::stoi(s, &n);
    if (n != s.size()) throw std::invalid_argument(s);
    return v;
  } catch (const std::exception&) {
    throw UsageError(std::string(what) + " expects an integer, got '" + s + "'");
  }
}

}  // namespace

int run_synth(const std::vector<std::string>& argv) {
  Args args(argv);
  if (args.help()) {
    std::puts(
        "usage: pbve synth [options] OUT_DIR\n"
        "\n"
        "Makes a synthetic input clip: a procedurally textured object moving in front of a static\n"
        "camera over a textured background. Writes OUT_DIR/clip.mp4 (or picture.png with\n"
        "--image), object.obj, poses.txt, plate_true.png and a ready scene.yaml for 'pbve edit'.\n"
        "\n"
        "options:\n"
        "  --shape S        board (default) | figurine | ball | statue (fractured, needs Bullet)\n"
        "  --motion M       swing (default) | wave | stop | push | bounce | orbit | still\n"
        "  --engine E       mass_spring | bullet (default: mass_spring, bullet for the statue)\n"
        "  --amplitude DEG  peak turn of swing (default 80) or stop (default 20)\n"
        "  --frequency HZ   turns per second of swing (default 0.9)\n"
        "  --frames N       number of frames (default 90)\n"
        "  --fps F          frame rate (default 30)\n"
        "  --size WxH       image size (default 640x480)\n"
        "  --supersample K  antialiasing samples per pixel along each axis (default 3)\n"
        "  --background P   background image (default: a generated one)\n"
        "  --image          a single picture (frame 0) instead of a video\n"
        "  --occluder       a hand passes in front of the object mid-clip (tracking tests)");
    return 0;
  }
  SynthOptions o;
  o.shape = args.value("--shape", {}, o.shape);
  o.motion = args.value("--motion", {}, o.motion);
  o.engine = args.value("--engine", {}, o.engine);
  o.frames = parse_int(args.value("--frames", {}, "90"), "--frames");
  auto positive = [&](const char* flag, const std::string& text) {
    try {
      size_t n = 0;
      const double v = std::stod(text, &n);
      if (n != text.size() || !(v > 0.0) || !std::isfinite(v)) throw std::invalid_argument(text);
      return v;
    } catch (const std::exception&) {
      throw UsageError(std::string(flag) + " expects a positive number, got '" + text + "'");
    }
  };
  o.fps = positive("--fps", args.value("--fps", {}, "30"));
  if (const std::string a = args.value("--amplitude"); !a.empty())
    o.amplitude_deg = positive("--amplitude", a);
  if (const std::string f = args.value("--frequency"); !f.empty())
    o.frequency_hz = positive("--frequency", f);
  o.supersample = parse_int(args.value("--supersample", {}, "3"), "--supersample");
  const std::string size = args.value("--size", {}, "640x480");
  const auto x = size.find('x');
  if (x == std::string::npos) throw UsageError("--size expects WxH, got '" + size + "'");
  o.width = parse_int(size.substr(0, x), "--size");
  o.height = parse_int(size.substr(x + 1), "--size");
  o.background = args.value("--background");
  o.single_image = args.flag("--image");
  o.occluder = args.flag("--occluder");
  if (o.single_image) {
    o.video_name = "picture.png";
    if (o.motion == "swing") o.motion = "still";
  }
  const auto pos = args.positional();
  if (pos.size() != 1) throw UsageError("expected one output folder");
  SynthOutput out;
  try {
    out = synthesize(o, pos[0]);
  } catch (const InputError& e) {
    // An option's value out of range (checked before any file is written) is bad usage.
    if (e.file().empty() && e.key().rfind("--", 0) == 0)
      throw UsageError(e.key() + ": " + e.message());
    throw;
  }
  std::printf("wrote %s\n      %s\n      %s\n      %s\nedit it with: pbve edit %s\n",
              out.video.c_str(), out.mesh.c_str(), out.poses.c_str(), out.scene.c_str(),
              out.scene.c_str());
  return 0;
}

int run_plot(const std::vector<std::string>& argv) {
  Args args(argv);
  if (args.help()) {
    std::puts(
        "usage: pbve plot REPORT.json [REPORT2.json] [-o PLOT.png] [--labels A,B]\n"
        "\n"
        "Draws the violation % per frame and the control vs physical force per frame of one or\n"
        "two reports (e.g. unconstrained and constrained) into a PNG, like the paper's Figures 7\n"
        "and 8. Default output: the first report's name with .png.");
    return 0;
  }
  std::string out = args.value("--output", "-o");
  const std::string labels_arg = args.value("--labels");
  const auto pos = args.positional();
  if (pos.empty() || pos.size() > 2) throw UsageError("expected one or two report files");
  std::vector<Report> reports;
  std::vector<std::string> labels;
  for (const auto& p : pos) {
    reports.push_back(read_report(p));
    labels.push_back(fs::path(p).stem().string());
  }
  if (!labels_arg.empty()) {
    labels.clear();
    size_t start = 0;
    while (start <= labels_arg.size()) {
      const size_t c = labels_arg.find(',', start);
      labels.push_back(
          labels_arg.substr(start, c == std::string::npos ? std::string::npos : c - start));
      if (c == std::string::npos) break;
      start = c + 1;
    }
  }
  if (labels.size() != reports.size())
    throw UsageError("--labels gives " + std::to_string(labels.size()) + " labels for " +
                     std::to_string(reports.size()) + " reports");
  if (out.empty()) out = fs::path(pos[0]).replace_extension(".png").string();
  const std::string ext = fs::path(out).extension().string();
  if (ext != ".png" && ext != ".PNG")
    throw UsageError("the plot is a PNG image: give -o NAME.png, got " + out);
  for (const auto& p : pos)
    if (same_file(out, p)) throw InputError("the plot would overwrite the report " + p, out);
  check_writable(out);
  const cv::Mat img = plot_reports(reports, labels);
  write_atomically(out, [&](const fs::path& tmp) {
    if (!cv::imwrite(tmp.string(), img)) throw InputError("cannot write the plot", out);
  });
  std::printf("wrote %s\n", out.c_str());
  return 0;
}

}  // namespace pbve::cli
