// Stage 4 in single precision (float pairs, float sums): one file per precision so that the many
// kernel instantiations compile side by side.
#include "forces/traversal_impl.cuh"

namespace cellforce::cuda {

template void traverse<float, float>(TraversalForm, const Switches&, const TraversalArgs<float, float>&,
                                    cudaStream_t);
template void traverse_local<float, float>(const Switches&, const TraversalArgs<float, float>&, cudaStream_t);

}  // namespace cellforce::cuda
