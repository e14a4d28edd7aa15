#pragma once
/// @file
/// Writing outputs without losing anything: temporary names that never replace an existing
/// file, moves into place that replace nothing but a regular file, and file identity.

#include <filesystem>
#include <system_error>

namespace pbve {

/// True when `a` and `b` name the same file (through hard links, symbolic links or different
/// spellings), or, when one of them does not exist yet, the same normalized path.
bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

/// The first temporary name tried for `path` while it is being written ("name.partial.ext").
std::filesystem::path partial_path(const std::filesystem::path& path);

/// Creates, exclusively and empty, a temporary file beside `path` to write it under:
/// partial_path(path), else "name.partial-2.ext", "name.partial-3.ext", ..., the first name no
/// file has, so that no existing file (an input among them) is ever written over. Throws
/// InputError naming the folder and the reason when it accepts no new file.
std::filesystem::path reserve_partial(const std::filesystem::path& path);

/// Checks before any work that `path` can be written: its folder exists and accepts new files
/// (probed with reserve_partial(), then removed), and `path` is not a folder nor any other
/// file than a regular one (a device, a pipe), which moving a finished file onto it would
/// replace. Throws InputError naming the path.
void check_writable(const std::filesystem::path& path);

/// Moves the finished temporary file `tmp` onto `path`. Refuses, like check_writable(), a
/// `path` that exists and is not a regular file. On failure removes `tmp` and throws InputError.
void commit_partial(const std::filesystem::path& tmp, const std::filesystem::path& path);

/// Writes a file atomically: `write` receives a temporary path reserved beside `path`
/// (reserve_partial()), which is moved onto `path` when it returns normally (commit_partial())
/// and removed when it throws.
template <class WriteFn>
void write_atomically(const std::filesystem::path& path, WriteFn&& write) {
  const std::filesystem::path tmp = reserve_partial(path);
  try {
    write(tmp);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove(tmp, ec);
    throw;
  }
  commit_partial(tmp, path);
}

}  // namespace pbve
