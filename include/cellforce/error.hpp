// cellforce::Error: what every failing call of the C++ API throws (bad input, a device that cannot
// be used, an internal fault). The message names the offending parameter, particle, file or step.
//
// The message lives in std::runtime_error alone (one layout for programs built with either value of
// _GLIBCXX_USE_CXX11_ABI): an Error thrown by the library reads the same in a program built with the
// other string ABI.
#pragma once

#include <cstring>
#include <stdexcept>
#include <string>

#include <cellforce/export.hpp>
#include <cellforce/version.h>

namespace cellforce {
inline namespace CELLFORCE_ABI_NAMESPACE {

class CELLFORCE_API Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error(kPrefix + what) {}
  // The message without the "cellforce: " prefix.
  std::string message() const { return what() + std::strlen(kPrefix); }

 private:
  static constexpr const char* kPrefix = "cellforce: ";
};

// A CUDA device that cannot be used or a CUDA call that failed (the C API's CF_ERROR_DEVICE);
// every other Error is about the input.
class CELLFORCE_API DeviceError : public Error {
 public:
  using Error::Error;
};

}  // namespace CELLFORCE_ABI_NAMESPACE
}  // namespace cellforce
