// cellforce::Error: what every failing call of the C++ API throws (bad input, a device that cannot
// be used, an internal fault). The message names the offending parameter, particle, file or step.
#pragma once

#include <stdexcept>
#include <string>

#include <cellforce/export.hpp>

namespace cellforce {

class CELLFORCE_API Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(kPrefix + what), message_(what) {}
  // The message without the "cellforce: " prefix.
  const std::string& message() const { return message_; }

 private:
  static inline const std::string kPrefix = "cellforce: ";
  std::string message_;
};

// A CUDA device that cannot be used or a CUDA call that failed (the C API's CF_ERROR_DEVICE);
// every other Error is about the input.
class CELLFORCE_API DeviceError : public Error {
 public:
  using Error::Error;
};

}  // namespace cellforce
