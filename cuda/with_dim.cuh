// Host-side dispatch on a run-time dimension: kernels that take the dimension as a template
// parameter (their loops unroll, their arrays stay in registers, their divisions by D are by a
// constant) are launched through with_dim.
#pragma once

#include <type_traits>

namespace cellforce::cuda {

// f(std::integral_constant<int, D>) for dim (2 or 3: scenes, the API and the readers reject any
// other).
template <class F>
void with_dim(int dim, F&& f) {
  if (dim == 2) f(std::integral_constant<int, 2>{});
  else f(std::integral_constant<int, 3>{});
}

}  // namespace cellforce::cuda
