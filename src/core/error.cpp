#include "pbve/core/error.hpp"

namespace pbve {

std::string format_location(const std::filesystem::path& file, int line, const std::string& key) {
  std::string s;
  if (!file.empty()) {
    s += file.string();
    if (line > 0) {
      s.push_back(':');
      s.append(std::to_string(line));
    }
    s.append(": ");
  } else if (line > 0) {
    s.append("line ").append(std::to_string(line)).append(": ");
  }
  if (!key.empty()) s.append(key).append(": ");
  return s;
}

InputError::InputError(const std::string& message, std::filesystem::path file, int line,
                       std::string key)
    : std::invalid_argument(format_location(file, line, key) + message),
      m_file(std::move(file)),
      m_line(line),
      m_key(std::move(key)),
      m_message(message) {}

}  // namespace pbve
