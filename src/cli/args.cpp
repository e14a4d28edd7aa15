#include <algorithm>

#include "cli/commands.hpp"

namespace pbve::cli {

bool Args::help() const {
  return std::find(m_args.begin(), m_args.end(), "--help") != m_args.end() ||
         std::find(m_args.begin(), m_args.end(), "-h") != m_args.end();
}

std::string Args::value(const std::string& name, const std::string& alias,
                        const std::string& fallback) {
  for (size_t i = 0; i < m_args.size(); ++i) {
    const std::string& a = m_args[i];
    if (a == name || (!alias.empty() && a == alias)) {
      if (i + 1 >= m_args.size()) throw UsageError("option " + a + " needs a value");
      std::string v = m_args[i + 1];
      m_args.erase(m_args.begin() + static_cast<long>(i),
                   m_args.begin() + static_cast<long>(i) + 2);
      reject_repeat(name, alias);
      return v;
    }
    if (a.rfind(name + "=", 0) == 0) {
      std::string v = a.substr(name.size() + 1);
      m_args.erase(m_args.begin() + static_cast<long>(i));
      reject_repeat(name, alias);
      return v;
    }
  }
  return fallback;
}

void Args::reject_repeat(const std::string& name, const std::string& alias) const {
  for (const auto& a : m_args)
    if (a == name || (!alias.empty() && a == alias) || a.rfind(name + "=", 0) == 0)
      throw UsageError("option " + name + " given twice");
}

bool Args::flag(const std::string& name) {
  auto it = std::find(m_args.begin(), m_args.end(), name);
  if (it == m_args.end()) return false;
  m_args.erase(it);
  if (std::find(m_args.begin(), m_args.end(), name) != m_args.end())
    throw UsageError("option " + name + " given twice");
  return true;
}

std::vector<std::string> Args::positional() const {
  for (const auto& a : m_args)
    if (a.size() > 1 && a[0] == '-') throw UsageError("unknown option " + a);
  return m_args;
}

}  // namespace pbve::cli
