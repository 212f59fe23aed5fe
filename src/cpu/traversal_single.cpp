// Stage 4, traversal, instantiated for single precision (float pairs, float sums).
#include "cpu/traversal_impl.h"

namespace cellforce::cpu {

template TraversalReport traverse<float, float>(const TraversalInput&, const Request&, Accumulation,
                                             Accumulators<float>&);

}  // namespace cellforce::cpu
