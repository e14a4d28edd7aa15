#pragma once
/// @file
/// Errors pbve reports for bad input: they say what was wrong and where.

#include <filesystem>
#include <stdexcept>
#include <string>

namespace pbve {

/// Bad input found while reading a file or checking a value at the API boundary.
///
/// what() reads "FILE:LINE: message", "FILE: key 'k': message", "FILE: message" or just
/// "message", depending on which of file(), line() and key() are known.
class InputError : public std::invalid_argument {
 public:
  /// @param message what was wrong, e.g. "expected 16 or 6 numbers, found 5"
  /// @param file    file at fault (may be empty)
  /// @param line    1-based line number, or 0 when not applicable
  /// @param key     scene-file key or element name (e.g. "vertex 12"), may be empty
  explicit InputError(const std::string& message, std::filesystem::path file = {}, int line = 0,
                      std::string key = {});

  const std::filesystem::path& file() const noexcept { return m_file; }
  int line() const noexcept { return m_line; }
  const std::string& key() const noexcept { return m_key; }
  /// The message without the location prefix.
  const std::string& message() const noexcept { return m_message; }

 private:
  std::filesystem::path m_file;
  int m_line = 0;
  std::string m_key;
  std::string m_message;
};

/// Formats the location prefix used by InputError ("file:line: ", "file: key 'k': ", ...).
std::string format_location(const std::filesystem::path& file, int line, const std::string& key);

}  // namespace pbve
