// The application's one way to the engine (the CLI's commands, the Python module's scenes): a
// cellforce::Context (the public API) set up from a description of a system (box, force field) and
// the engine options it was given (a scene's [run] and [neighbor], a command's flags), handed to
// Context::set_option as they are.
#pragma once

#include <cellforce/cellforce.hpp>
#include <string>

#include "core/box.h"
#include "core/force_field.h"
#include "core/option_table.h"

namespace cellforce {

// The command line's flag of an option: --KEY, the option table's key.
inline std::string option_flag(OptionId id) { return "--" + std::string(option_key(id)); }

// The engine options every command starts from: the backend auto (a CUDA device when one can be
// used; a new Context's default is the CPU), the rest as a new Context has them.
OptionList command_engine_defaults();

// A context for `box` with the force field's cutoff, mixing, types and explicit pairs, and the
// engine options in their order (set_option). Throws cellforce::Error naming what the API refuses.
Context make_context(const Box& box, const ForceField& ff, const OptionList& engine);

}  // namespace cellforce
