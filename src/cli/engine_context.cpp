#include "cli/engine_context.h"

#include <string>

#include "core/names.h"

namespace cellforce {

Context make_context(const Box& box, const ForceField& ff, const EngineChoice& engine) {
  Context ctx(box.dim);
  const bool periodic[3] = {box.periodic[0], box.periodic[1], box.periodic[2]};
  ctx.set_box(box.length, periodic);
  ctx.set_cutoff(ff.cutoff, ff.mode);
  ctx.set_mixing(ff.mixing);
  for (const ParticleType& t : ff.types) ctx.add_type(t.name, t.sigma, t.epsilon);
  for (const PairOverride& o : ff.overrides) ctx.set_pair(uint32_t(o.a), uint32_t(o.b), o.sigma, o.epsilon);
  ctx.set_backend(engine.backend, engine.device);
  ctx.set_precision(engine.precision);
  if (engine.reuse.automatic) ctx.set_option("skin", "auto");  // the engine's rule picks skin and lists
  else ctx.set_skin(engine.reuse.skin);
  ctx.set_option("neighbor-check", engine.reuse.check ? "true" : "false");
  ctx.set_option("neighbor-every", std::to_string(engine.reuse.every));
  ctx.set_option("neighbor-audit", engine.reuse.audit ? "true" : "false");
  if (!engine.reuse.automatic) ctx.set_option("neighbor-list", engine.reuse.list ? "true" : "false");
  ctx.set_option("accumulation", name_of(engine.accumulation, kAccumulationNames));
  ctx.set_option("cell-rule", name_of(engine.rule, kCellRuleNames));
  ctx.set_option("traversal", name_of(engine.traversal, kTraversalNames));
  ctx.set_option("sort", name_of(engine.sort, kSortNames));
  ctx.set_option("memory", name_of(engine.memory, kListMemoryNames));
  return ctx;
}

}  // namespace cellforce
