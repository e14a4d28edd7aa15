// pbve bench: example 1 (board to cloth) at several mesh resolutions, without control and with
// control (adjoint and central-difference gradients), timed end to end; one JSON out.

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"
#include "pbve/config.hpp"
#include "pbve/core/error.hpp"
#include "pbve/core/files.hpp"
#include "pbve/core/mesh.hpp"
#include "pbve/edit/editor.hpp"
#include "pbve/edit/scene.hpp"
#include "pbve/edit/synth.hpp"
#include "pbve/engines.hpp"

namespace pbve::cli {

namespace {

namespace fs = std::filesystem;
using nlohmann::json;

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, sep))
    if (!item.empty()) out.push_back(item);
  return out;
}

int parse_int(const std::string& option, const std::string& text) {
  try {
    size_t used = 0;
    const int v = std::stoi(text, &used);
    if (used == text.size()) return v;
  } catch (const std::exception&) {
  }
  throw UsageError(option + " expects an integer, got '" + text + "'");
}

double median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// The edge length whose refinement of `mesh` has the vertex count closest to `target`
/// (searched over lengths shrinking by 2^(1/8) from the longest edge).
std::pair<double, int> refine_for(const Mesh& mesh, int target) {
  double best_len = 0.0;
  int best_count = mesh.num_vertices();
  double len = max_edge_length(mesh);
  for (int k = 0; k < 200; ++k) {
    len /= std::pow(2.0, 1.0 / 8.0);
    const int count = refine_mesh(mesh, len).num_vertices();
    if (std::abs(count - target) < std::abs(best_count - target)) {
      best_count = count;
      best_len = len;
    }
    if (count > 2 * target) break;
  }
  return {best_len, best_count};
}

std::string host_name() {
  char buf[256] = {};
  if (::gethostname(buf, sizeof buf - 1) != 0) return "unknown";
  return buf;
}

/// The 1-minute load average (other work on the machine skews the timings), or -1.
double load_average() {
  std::ifstream f("/proc/loadavg");
  double v = -1.0;
  f >> v;
  return f ? v : -1.0;
}

std::string utc_now() {
  const std::time_t t = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buf;
}

const char* kHelp =
    "usage: pbve bench [-o BENCH.json] [--vertices 1000,4000,16000] [--frames A:B]\n"
    "                  [--modes unconstrained,adjoint,central] [--central-max-vertices N]\n"
    "                  [--size WxH] [--work DIR] [--quiet]\n"
    "\n"
    "End-to-end benchmark on example 1 (board to cloth): makes its synthetic clip, then edits\n"
    "input frames A:B with the mesh refined to about each requested vertex count, once per mode:\n"
    "  unconstrained  no control (the simulation, visibility and rendering alone)\n"
    "  adjoint        control with adjoint gradients (mass_spring's step_vjp)\n"
    "  central        control with central-difference gradients, parallel over simulator clones\n"
    "and writes the per-run timings (ms per frame: mean and median over the simulated frames,\n"
    "optimizer share), violation and force figures into one JSON file.\n"
    "\n"
    "Central differences cost two simulations per optimized variable and per gradient; runs\n"
    "above --central-max-vertices are recorded as skipped (with the reason) instead of run.\n"
    "\n"
    "options:\n"
    "  -o, --output FILE          JSON output (default: bench.json)\n"
    "  --vertices LIST            target vertex counts (default: 1000,4000,16000)\n"
    "  --frames A:B               input frames to edit (default: 14:24; frame A is the rest\n"
    "                             frame, the following ones are simulated and timed)\n"
    "  --modes LIST               any of unconstrained,adjoint,central (default: all three)\n"
    "  --central-max-vertices N   largest mesh run with central differences (default: 1500)\n"
    "  --size WxH                 clip size (default: 640x480)\n"
    "  --work DIR                 keep the clip, videos and reports in DIR (default: a\n"
    "                             temporary folder, removed at the end)\n"
    "  --quiet                    no progress lines\n"
    "\n"
    "exit status: 0 when the JSON file was written, 1 on error, 2 on bad usage, 130 when\n"
    "interrupted (Ctrl-C or SIGTERM: the temporary folder removed, no JSON written).";

}  // namespace

int run_bench(const std::vector<std::string>& argv) {
  Args args(argv);
  if (args.help()) {
    std::puts(kHelp);
    return 0;
  }
  const fs::path out = args.value("--output", "-o", "bench.json");
  std::vector<int> targets;
  for (const auto& s : split(args.value("--vertices", {}, "1000,4000,16000"), ',')) {
    targets.push_back(parse_int("--vertices", s));
    if (targets.back() <= 0) throw UsageError("--vertices: a target must be positive, got " + s);
  }
  const std::string frames_spec = args.value("--frames", {}, "14:24");
  const auto colon = frames_spec.find(':');
  if (colon == std::string::npos) throw UsageError("--frames expects A:B");
  const int first = parse_int("--frames", frames_spec.substr(0, colon));
  const int end = parse_int("--frames", frames_spec.substr(colon + 1));
  if (first < 0 || end <= first + 1)
    throw UsageError("--frames " + frames_spec + " needs at least two frames");
  const std::vector<std::string> modes =
      split(args.value("--modes", {}, "unconstrained,adjoint,central"), ',');
  if (modes.empty()) throw UsageError("--modes is empty");
  for (const auto& m : modes)
    if (m != "unconstrained" && m != "adjoint" && m != "central")
      throw UsageError("unknown mode '" + m + "' (expected unconstrained, adjoint or central)");
  const int central_max =
      parse_int("--central-max-vertices", args.value("--central-max-vertices", {}, "1500"));
  const std::string size = args.value("--size", {}, "640x480");
  const fs::path work_arg = args.value("--work");
  const bool quiet = args.flag("--quiet");
  if (!args.positional().empty()) throw UsageError("unexpected argument");
  if (targets.empty()) throw UsageError("--vertices is empty");
  const bool tty = ::isatty(STDERR_FILENO) != 0;

  SynthOptions so;
  so.shape = "board";
  so.motion = "swing";
  so.frames = end;
  {
    const auto x = size.find('x');
    if (x == std::string::npos) throw UsageError("--size expects WxH, got '" + size + "'");
    so.width = parse_int("--size", size.substr(0, x));
    so.height = parse_int("--size", size.substr(x + 1));
    if (so.width < 16 || so.height < 16) throw UsageError("--size is too small: " + size);
  }
  const fs::path out_dir = out.has_parent_path() ? out.parent_path() : fs::path(".");
  if (!fs::is_directory(out_dir))
    throw std::runtime_error("the output folder " + out_dir.string() + " does not exist");

  check_writable(out);
  // --work DIR receives the clip, its mesh, scene, videos and reports: a new or empty folder,
  // so that none of its files is written over.
  if (std::error_code ec; !work_arg.empty() && fs::exists(work_arg, ec) &&
                          !(fs::is_directory(work_arg, ec) && fs::is_empty(work_arg, ec)))
    throw UsageError("--work " + work_arg.string() + " must be a new or empty folder");
  const InterruptGuard guard;  // from here on a signal stops at the next check, cleaning up
  const bool keep = !work_arg.empty();
  const fs::path work =
      keep ? work_arg : fs::temp_directory_path() / ("pbve-bench-" + std::to_string(::getpid()));
  fs::create_directories(work);
  struct Cleanup {
    fs::path dir;
    bool keep;
    ~Cleanup() {
      std::error_code ec;
      if (!keep) fs::remove_all(dir, ec);
    }
  } cleanup{work, keep};

  if (!quiet) std::fprintf(stderr, "making example 1's clip (%d frames, %s)\n", end, size.c_str());
  const double load_before = load_average();
  const SynthOutput clip = synthesize(so, work);
  const Scene base = load_scene(clip.scene);
  check_engine(base);
  const Mesh mesh = load_mesh(clip.mesh);

  if (interrupted()) throw Interrupted("interrupted: no benchmark file written");
  json runs = json::array();
  for (const int target : targets) {
    const auto [refine, vertices] = refine_for(mesh, target);
    for (const std::string& mode : modes) {
      json run = {
          {"target_vertices", target}, {"vertices", vertices}, {"refine", refine}, {"mode", mode}};
      if (mode == "central" && vertices > central_max) {
        run["skipped"] = true;
        run["reason"] = "central differences above --central-max-vertices " +
                        std::to_string(central_max) +
                        " (two simulations per optimized variable per gradient)";
        runs.push_back(run);
        if (!quiet) std::fprintf(stderr, "%6d vertices  %-13s skipped\n", vertices, mode.c_str());
        continue;
      }
      Scene scene = base;
      scene.object.refine = refine;
      EditOptions o;
      o.first_frame = first;
      o.end_frame = end;
      o.control = mode != "unconstrained";
      if (mode != "unconstrained") scene.control.gradient = mode;
      const std::string stem = std::to_string(vertices) + "_" + mode;
      o.video = work / (stem + ".mp4");
      o.report = work / (stem + ".json");
      EditCallbacks cb;
      cb.make_simulator = [](const EngineRecipe& r) { return make_engine(r); };
      if (!quiet && tty)
        cb.progress = [&](const EditProgress& p) {
          std::fprintf(stderr, "\r%6d vertices  %-13s frame %d/%d", vertices, mode.c_str(), p.frame,
                       p.total);
          std::fflush(stderr);
        };
      cb.cancel = [] { return interrupted(); };
      const EditResult r = run_edit(scene, o, cb);
      if (r.status == EditStatus::cancelled || interrupted())
        throw Interrupted("interrupted: no benchmark file written");
      std::vector<double> frame_ms, solve_ms;
      for (const FrameRecord& f : r.report.frames) {
        if (f.status == "rest") continue;  // nothing simulated in the first frame
        frame_ms.push_back(f.frame_ms);
        solve_ms.push_back(f.solve_ms);
      }
      double frame_mean = 0.0;
      for (double v : frame_ms) frame_mean += v;
      if (!frame_ms.empty()) frame_mean /= static_cast<double>(frame_ms.size());
      const ReportSummary s = r.report.summary();
      run["frames"] = json::array({first, end});
      run["simulated_frames"] = frame_ms.size();
      run["ms_per_frame_median"] = median(frame_ms);
      run["ms_per_frame_mean"] = frame_mean;
      run["solve_ms_median"] = median(solve_ms);
      run["violation_pct_mean"] = s.violation_pct_mean;
      run["violation_pct_max"] = s.violation_pct_max;
      run["control_to_physical_force_median"] = s.control_to_physical_force_median;
      run["engine"] = r.report.engine;
      runs.push_back(run);
      if (!quiet)
        std::fprintf(stderr,
                     "%s%6d vertices  %-13s %9.1f ms/frame (median)  violation mean %.3f%%  "
                     "max %.3f%%\n",
                     tty ? "\r" : "", vertices, mode.c_str(), median(frame_ms),
                     s.violation_pct_mean, s.violation_pct_max);
    }
  }

  // Cost of control relative to the uncontrolled run at the same resolution.
  for (json& run : runs) {
    if (run.value("skipped", false) || run["mode"] == "unconstrained") continue;
    for (const json& base_run : runs)
      if (base_run["mode"] == "unconstrained" && base_run["vertices"] == run["vertices"] &&
          base_run["ms_per_frame_median"].get<double>() > 0.0)
        run["cost_vs_unconstrained"] = run["ms_per_frame_median"].get<double>() /
                                       base_run["ms_per_frame_median"].get<double>();
  }

  json doc = {{"pbve_version", version_string},
              {"example", "board_to_cloth"},
              {"date_utc", utc_now()},
              {"host", host_name()},
              {"hardware_threads", std::thread::hardware_concurrency()},
              {"load_average_1min", {{"start", load_before}, {"end", load_average()}}},
              {"size", {so.width, so.height}},
              {"command", "pbve bench " +
                              [&] {
                                std::string c;
                                for (const auto& a : argv) c += (c.empty() ? "" : " ") + a;
                                return c;
                              }()},
              {"runs", runs}};
  write_atomically(out, [&](const fs::path& tmp) {
    std::ofstream f(tmp);
    f << doc.dump(2) << "\n";
    f.flush();
    if (!f) throw InputError("cannot write the benchmark file (disk full?)", out);
  });
  std::printf("wrote %s\n", out.c_str());
  return 0;
}

}  // namespace pbve::cli
