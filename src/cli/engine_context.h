// The commands' one way to the engine: a cellforce::Context (the public API) set up from the
// application's typed description of a system (box, force field) and of the engine to use.
#pragma once

#include <cellforce/cellforce.hpp>

#include "backends/force_engine.h"  // EngineChoice
#include "core/box.h"
#include "core/force_field.h"

namespace cellforce {

// A context for `box` with the force field's cutoff, mixing, types and explicit pairs, and every
// engine choice (backend and device, precision, skin and its check, limit and audit, accumulation,
// cell rule, CUDA traversal and sort). Throws cellforce::Error naming what the API refuses.
Context make_context(const Box& box, const ForceField& ff, const EngineChoice& engine);

}  // namespace cellforce
