#include "scene/engine_context.h"

#include "core/names.h"

namespace cellforce {

OptionList command_engine_defaults() {
  OptionList engine;
  engine.set(OptionId::kBackend, name_of(Backend::kAuto, kBackendNames));
  return engine;
}

Context make_context(const Box& box, const ForceField& ff, const OptionList& engine) {
  Context ctx(box.dim);
  const bool periodic[3] = {box.periodic[0], box.periodic[1], box.periodic[2]};
  ctx.set_box(box.length, periodic);
  ctx.set_cutoff(ff.cutoff, ff.mode);
  ctx.set_mixing(ff.mixing);
  for (const ParticleType& t : ff.types) ctx.add_type(t.name, t.sigma, t.epsilon);
  for (const PairOverride& o : ff.overrides) ctx.set_pair(uint32_t(o.a), uint32_t(o.b), o.sigma, o.epsilon);
  for (const OptionList::Entry& option : engine.entries()) ctx.set_option(option.key(), option.value);
  return ctx;
}

}  // namespace cellforce
