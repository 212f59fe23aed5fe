// LAMMPS's class headers for cellforce-lammps. Debian's liblammps-dev (LAMMPS 29Sep2021) ships
// headers that include fmt but not fmt itself; with Debian's fmt 9 they name one function fmt 9
// no longer has (make_args_checked, in a template of utils.h that this program never
// instantiates), which is declared here first so that the headers compile.
#pragma once

#include <fmt/format.h>

#if FMT_VERSION >= 90000
namespace fmt {
template <typename... Args, typename S>
auto make_args_checked(const S&, const Args&... args) {
  return fmt::make_format_args(args...);
}
}  // namespace fmt
#endif

#include <atom.h>
#include <comm.h>
#include <domain.h>
#include <error.h>
#include <force.h>
#include <input.h>
#include <lammps.h>
#include <memory.h>
#include <neighbor.h>
#include <pair.h>
