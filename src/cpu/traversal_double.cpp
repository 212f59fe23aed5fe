// Stage 4, traversal, instantiated for double precision (double pairs, double sums).
#include "cpu/traversal_impl.h"

namespace cellforce::cpu {

template TraversalReport traverse<double, double>(const TraversalInput&, const Request&, Accumulation,
                                             Accumulators<double>&);

}  // namespace cellforce::cpu
