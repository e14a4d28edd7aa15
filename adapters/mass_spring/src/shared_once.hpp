#pragma once
// A read-only object built on first use, once, whichever thread asks first, then shared by
// every user (a model's symbolic analysis or multigrid hierarchy, shared by its clones).

#include <memory>
#include <mutex>

namespace pbve::mass_spring::detail {

template <class T>
class SharedOnce {
 public:
  /// The object, made by build() (returning std::shared_ptr<const T>) on the first call.
  template <class Build>
  std::shared_ptr<const T> get(Build build) const {
    std::call_once(m_once, [&] { m_value = build(); });
    return m_value;
  }

 private:
  mutable std::once_flag m_once;
  mutable std::shared_ptr<const T> m_value;
};

}  // namespace pbve::mass_spring::detail
