#include "pbve/core/files.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <string>

#include "pbve/core/error.hpp"

namespace fs = std::filesystem;

namespace pbve {

namespace {

fs::path folder_of(const fs::path& path) {
  return path.has_parent_path() ? path.parent_path() : fs::path(".");
}

// Empty when `path` does not exist or is a regular file, else what it is.
std::string not_regular(const fs::path& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st) || fs::is_regular_file(st)) return {};
  if (fs::is_directory(st)) return "a folder";
  if (fs::is_fifo(st)) return "a pipe";
  if (fs::is_character_file(st) || fs::is_block_file(st)) return "a device";
  if (fs::is_socket(st)) return "a socket";
  return "not a regular file";
}

}  // namespace

bool same_file(const fs::path& a, const fs::path& b) {
  if (a.empty() || b.empty()) return false;
  std::error_code ec;
  if (fs::exists(a, ec) && fs::exists(b, ec)) return fs::equivalent(a, b, ec);
  // Absolute first: weakly_canonical leaves a relative path whose first part does not exist
  // as it is ("x" against "./x").
  return fs::weakly_canonical(fs::absolute(a, ec), ec) ==
         fs::weakly_canonical(fs::absolute(b, ec), ec);
}

namespace {
// "name.partial.ext" (k = 1), "name.partial-k.ext" (k > 1).
fs::path partial_name(const fs::path& path, int k) {
  fs::path name = path.stem();
  name += k > 1 ? ".partial-" + std::to_string(k) : std::string(".partial");
  name += path.extension();
  return path.parent_path() / name;
}
}  // namespace

fs::path partial_path(const fs::path& path) {
  return partial_name(path, 1);
}

fs::path reserve_partial(const fs::path& path) {
  for (int k = 1;; ++k) {
    const fs::path tmp = partial_name(path, k);
    // 0666: the user's umask applies, as for a file the writer would create itself.
    const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0666);
    if (fd >= 0) {
      ::close(fd);
      return tmp;
    }
    const int err = errno;  // before anything else can change it
    if (err != EEXIST || k >= 1000)
      throw InputError("cannot create files in the output folder " + folder_of(path).string() +
                           ": " + std::generic_category().message(err),
                       path);
  }
}

void check_writable(const fs::path& path) {
  std::error_code ec;
  const fs::path dir = folder_of(path);
  if (!fs::is_directory(dir, ec))
    throw InputError("the output folder " + dir.string() + " does not exist", path);
  const std::string what = not_regular(path);
  if (!what.empty())
    throw InputError("the output " + path.string() + " is " + what + ", not a file it can replace",
                     path);
  fs::remove(reserve_partial(path), ec);
}

void commit_partial(const fs::path& tmp, const fs::path& path) {
  std::error_code ec;
  const std::string what = not_regular(path);
  if (!what.empty()) {
    fs::remove(tmp, ec);
    throw InputError("the output " + path.string() + " is " + what + ", not a file it can replace",
                     path);
  }
  fs::rename(tmp, path, ec);
  if (ec) {
    const std::string reason = ec.message();
    std::error_code ignored;
    fs::remove(tmp, ignored);
    throw InputError("cannot move the finished file into place: " + reason, path);
  }
}

}  // namespace pbve
