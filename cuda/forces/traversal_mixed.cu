// Stage 4 in mixed precision (float pairs, double sums): one file per precision so that the many
// kernel instantiations compile side by side.
#include "forces/traversal_impl.cuh"

namespace cellforce::cuda {

template void traverse<float, double>(TraversalForm, const Switches&, const TraversalArgs<float, double>&,
                                    cudaStream_t);
template void traverse_local<float, double>(const Switches&, const TraversalArgs<float, double>&, cudaStream_t);

}  // namespace cellforce::cuda
