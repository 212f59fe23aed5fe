// Host-side errors. Kernels and hot loops never throw: they raise flags that the host reads once
// and turns into one of these, with the particle, parameter or file named in the message.
#pragma once

#include <stdexcept>
#include <string>

namespace cellforce {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(kPrefix + what), message_(what) {}
  // The message without the "cellforce: " prefix.
  const std::string& message() const { return message_; }

 private:
  static inline const std::string kPrefix = "cellforce: ";
  std::string message_;
};

// Runs f; a cellforce::Error it throws comes out with "context: " before its message (the file
// or scene, and the step, that the inner code does not know about).
template <class F>
auto with_context(const std::string& context, F&& f) {
  try {
    return f();
  } catch (const Error& e) {
    throw Error(context + ": " + e.message());
  }
}

}  // namespace cellforce
