// Stage 4 in double precision (double pairs, double sums): one file per precision so that the many
// kernel instantiations compile side by side.
#include "forces/traversal_impl.cuh"

namespace cellforce::cuda {

template void traverse<double, double>(TraversalForm, const Switches&, const TraversalArgs<double, double>&,
                                    cudaStream_t);
template void traverse_local<double, double>(const Switches&, const TraversalArgs<double, double>&, cudaStream_t);

}  // namespace cellforce::cuda
