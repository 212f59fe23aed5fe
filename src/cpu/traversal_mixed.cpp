// Stage 4, traversal, instantiated for mixed precision (float pairs, double sums).
#include "cpu/traversal_impl.h"

namespace cellforce::cpu {

template TraversalReport traverse<float, double>(const TraversalInput&, const Request&, Accumulation,
                                             Accumulators<double>&);

}  // namespace cellforce::cpu
