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

}  // namespace

InterruptGuard::InterruptGuard() {
  g_interrupted = false;
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
}

InterruptGuard::~InterruptGuard() {
  std::signal(SIGINT, SIG_DFL);
  std::signal(SIGTERM, SIG_DFL);
}

bool interrupted() {
  return g_interrupted.load();
}

}  // namespace pbve::cli
