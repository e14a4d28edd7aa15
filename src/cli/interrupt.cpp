// SIGINT / SIGTERM as a request to stop cleanly (cli/commands.hpp).

#include <atomic>
#include <csignal>

#include "cli/commands.hpp"

namespace pbve::cli {

namespace {

std::atomic<bool> g_interrupted{false};

extern "C" void on_signal(int sig) {
  g_interrupted.store(true);
  std::signal(sig, SIG_DFL);  // a second signal stops at once
}

// The dispositions before the guard: restored after it. A signal the process inherited as
// ignored (a background job of a script) stays ignored.
void (*g_previous[2])(int) = {SIG_DFL, SIG_DFL};
constexpr int kSignals[2] = {SIGINT, SIGTERM};

}  // namespace

InterruptGuard::InterruptGuard() {
  g_interrupted = false;
  for (int k = 0; k < 2; ++k) {
    g_previous[k] = std::signal(kSignals[k], on_signal);
    if (g_previous[k] == SIG_IGN) std::signal(kSignals[k], SIG_IGN);
  }
}

InterruptGuard::~InterruptGuard() {
  for (int k = 0; k < 2; ++k) std::signal(kSignals[k], g_previous[k]);
}

bool interrupted() {
  return g_interrupted.load();
}

}  // namespace pbve::cli
