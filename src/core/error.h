// Host-side errors. Kernels and hot loops never throw: they raise flags that the host reads once
// and turns into one of these, with the particle, parameter or file named in the message.
#pragma once

#include <string>

#include <cellforce/error.hpp>  // cellforce::Error, part of the public API

namespace cellforce {

// The same kind of error (DeviceError stays one) with `prefix` before its message.
[[noreturn]] inline void rethrow_with(const std::string& prefix, const Error& e) {
  if (dynamic_cast<const DeviceError*>(&e)) throw DeviceError(prefix + e.message());
  throw Error(prefix + e.message());
}

// Runs f; a cellforce::Error it throws comes out with "context: " before its message (the file
// or scene, and the step, that the inner code does not know about).
template <class F>
auto with_context(const std::string& context, F&& f) {
  try {
    return f();
  } catch (const Error& e) {
    rethrow_with(context + ": ", e);
  }
}

}  // namespace cellforce
