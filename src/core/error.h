// Host-side errors. Kernels and hot loops never throw: they raise flags that the host reads once
// and turns into one of these, with the particle, parameter or file named in the message.
#pragma once

#include <stdexcept>
#include <string>

namespace cellforce {

class Error : public std::runtime_error {
 public:
  explicit Error(const std::string& what) : std::runtime_error("cellforce: " + what) {}
};

}  // namespace cellforce
