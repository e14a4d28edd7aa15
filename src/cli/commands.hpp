#pragma once
// Subcommands of the pbve command-line tool.

#include <stdexcept>
#include <string>
#include <vector>

namespace pbve::cli {

/// Bad command-line usage (exit status 2).
class UsageError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// A command stopped by SIGINT or SIGTERM before it finished (exit status 130): what it was
/// writing has been removed.
class Interrupted : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// While alive, SIGINT and SIGTERM set interrupted() instead of ending the process (a second
/// signal ends it at once), so that a command stops at its next check and unwinds: temporary
/// files removed, outputs left as they were.
class InterruptGuard {
 public:
  InterruptGuard();
  ~InterruptGuard();
  InterruptGuard(const InterruptGuard&) = delete;
  InterruptGuard& operator=(const InterruptGuard&) = delete;
};
/// A signal arrived while an InterruptGuard was alive.
bool interrupted();

/// Small argument scanner: options are --name VALUE, --flag, or -o VALUE.
class Args {
 public:
  explicit Args(std::vector<std::string> args) : m_args(std::move(args)) {}
  bool help() const;
  /// Removes and returns the value of `name` (and its short alias), or `fallback`.
  std::string value(const std::string& name, const std::string& alias = {},
                    const std::string& fallback = {});
  /// Removes `name`; true when it was present.
  bool flag(const std::string& name);
  /// The remaining arguments; throws UsageError for leftover options.
  std::vector<std::string> positional() const;

 private:
  void reject_repeat(const std::string& name, const std::string& alias) const;
  std::vector<std::string> m_args;
};

int run_edit(const std::vector<std::string>& args);
int run_synth(const std::vector<std::string>& args);
int run_plot(const std::vector<std::string>& args);
int run_bench(const std::vector<std::string>& args);
int run_track(const std::vector<std::string>& args);

}  // namespace pbve::cli
