#pragma once
// Running the pbve command from tests: run to completion and capture the output, or start it
// as a child process that can be signalled while it runs.

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace pbve::test {

/// The pbve binary of this build.
inline std::string pbve_binary() {
  return std::string(PBVE_BINARY_DIR) + "/bin/pbve";
}

/// Exit status and combined stdout + stderr of a finished command.
struct CmdResult {
  int status = -1;  ///< exit status, or -1 when the process did not exit normally
  std::string output;
};

/// Runs `pbve ARGS` through the shell (ARGS is pasted as is) and waits for it.
inline CmdResult pbve_cmd(const std::string& args) {
  const std::string cmd = pbve_binary() + " " + args + " 2>&1";
  CmdResult r;
  FILE* p = ::popen(cmd.c_str(), "r");
  if (!p) return r;
  char buf[4096];
  while (size_t n = std::fread(buf, 1, sizeof buf, p)) r.output.append(buf, n);
  const int st = ::pclose(p);
  r.status = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
  return r;
}

/// The two runs of `pbve edit` that the examples make: with `--no-control`, writing
/// UNCONSTRAINED.mp4 and UNCONSTRAINED.json, then with the scene's control and its own outputs.
/// SCENE_ARGS is the scene file and any further options; the second run is skipped (status -1)
/// when the first fails.
struct EditRuns {
  CmdResult unconstrained, controlled;
};
inline EditRuns edit_without_and_with_control(const std::string& scene_args,
                                              const std::filesystem::path& unconstrained) {
  EditRuns r;
  r.unconstrained = pbve_cmd("edit " + scene_args + " --no-control -o " + unconstrained.string() +
                             ".mp4 --report " + unconstrained.string() + ".json");
  if (r.unconstrained.status == 0) r.controlled = pbve_cmd("edit " + scene_args);
  return r;
}

/// The whole content of a file ("" when it cannot be read).
inline std::string read_text(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// A running `pbve` child process; its stdout and stderr are read through one pipe.
class PbveProcess {
 public:
  explicit PbveProcess(const std::vector<std::string>& args) {
    int fds[2];
    if (::pipe(fds) != 0) return;
    const std::string bin = pbve_binary();
    m_pid = ::fork();
    if (m_pid == 0) {
      ::dup2(fds[1], STDOUT_FILENO);
      ::dup2(fds[1], STDERR_FILENO);
      ::close(fds[0]);
      ::close(fds[1]);
      std::vector<char*> argv;
      argv.push_back(const_cast<char*>(bin.c_str()));
      for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
      argv.push_back(nullptr);
      ::execv(bin.c_str(), argv.data());
      ::_exit(127);
    }
    ::close(fds[1]);
    m_fd = fds[0];
  }
  PbveProcess(const PbveProcess&) = delete;
  PbveProcess& operator=(const PbveProcess&) = delete;
  ~PbveProcess() {
    if (m_pid > 0 && !m_waited) {
      ::kill(m_pid, SIGKILL);
      ::waitpid(m_pid, nullptr, 0);
    }
    if (m_fd >= 0) ::close(m_fd);
  }

  bool started() const { return m_pid > 0 && m_fd >= 0; }
  pid_t pid() const { return m_pid; }

  /// Reads output until a line containing `text` is complete; false at end of output.
  bool wait_for_line(const std::string& text) {
    for (;;) {
      for (size_t start = m_scanned, nl; (nl = m_output.find('\n', start)) != std::string::npos;
           start = nl + 1) {
        m_scanned = nl + 1;
        if (m_output.substr(start, nl - start).find(text) != std::string::npos) return true;
      }
      if (!read_some()) return false;
    }
  }

  void send(int signal) { ::kill(m_pid, signal); }

  /// Reads the rest of the output and waits for the exit; returns the exit status, or
  /// 128 + signal when the process was killed by a signal.
  int wait() {
    while (read_some()) {
    }
    int st = 0;
    ::waitpid(m_pid, &st, 0);
    m_waited = true;
    return WIFEXITED(st) ? WEXITSTATUS(st) : 128 + WTERMSIG(st);
  }

  const std::string& output() const { return m_output; }

 private:
  bool read_some() {
    char buf[4096];
    for (;;) {
      const ssize_t n = ::read(m_fd, buf, sizeof buf);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) return false;
      m_output.append(buf, static_cast<size_t>(n));
      return true;
    }
  }

  pid_t m_pid = -1;
  int m_fd = -1;
  bool m_waited = false;
  std::string m_output;
  size_t m_scanned = 0;
};

}  // namespace pbve::test
