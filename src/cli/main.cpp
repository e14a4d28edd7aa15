// pbve: physically based video editing from the command line.
//
//   pbve edit SCENE.yaml [-o OUT.mp4] [--report R.json] [--no-control] [--frames A:B]
//   pbve synth [--shape S] [--motion M] [--frames N] [--size WxH] [--image] OUT_DIR
//   pbve plot REPORT.json [REPORT2.json] [-o PLOT.png]
//   pbve bench [-o BENCH.json] [--vertices LIST] [--frames A:B] [--modes LIST]
//   pbve track VIDEO MESH --camera fx,fy,cx,cy --initial-pose P.txt -o POSES.txt

#include <cstdio>
#include <cstring>
#include <exception>
#include <iostream>
#include <string>
#include <vector>

#include "cli/commands.hpp"
#include "pbve/config.hpp"

namespace {

const char* kUsage =
    "usage: pbve <command> [options]\n"
    "\n"
    "Physically based video editing: footage of a rigid object in, footage of the object with\n"
    "new physics out.\n"
    "\n"
    "commands:\n"
    "  edit SCENE.yaml   simulate, control and render: writes the edited video and a report\n"
    "  synth OUT_DIR     make a synthetic input clip, its pose file and a scene file\n"
    "  plot REPORT.json  draw violation and force plots of one or two reports into a PNG\n"
    "  bench             time example 1 at several mesh resolutions, with and without control\n"
    "  track VIDEO MESH  estimate the object's pose in every frame (writes a pose file)\n"
    "\n"
    "Run 'pbve <command> --help' for the options of a command.\n";

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty() || args[0] == "--help" || args[0] == "-h" || args[0] == "help") {
    std::fputs(kUsage, args.empty() ? stderr : stdout);
    return args.empty() ? 2 : 0;
  }
  if (args[0] == "--version") {
    std::printf("pbve %s\n", pbve::version_string);
    return 0;
  }
  const std::string cmd = args[0];
  args.erase(args.begin());
  try {
    if (cmd == "edit") return pbve::cli::run_edit(args);
    if (cmd == "synth") return pbve::cli::run_synth(args);
    if (cmd == "plot") return pbve::cli::run_plot(args);
    if (cmd == "bench") return pbve::cli::run_bench(args);
    if (cmd == "track") return pbve::cli::run_track(args);
    std::fprintf(stderr, "pbve: unknown command '%s'\n\n%s", cmd.c_str(), kUsage);
    return 2;
  } catch (const pbve::cli::Interrupted& e) {
    std::fprintf(stderr, "pbve %s: %s\n", cmd.c_str(), e.what());
    return 130;
  } catch (const pbve::cli::UsageError& e) {
    std::fprintf(stderr, "pbve %s: %s\n(run 'pbve %s --help' for usage)\n", cmd.c_str(), e.what(),
                 cmd.c_str());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "pbve %s: error: %s\n", cmd.c_str(), e.what());
    return 1;
  }
}
