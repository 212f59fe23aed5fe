// Context::statistics_json and cf_statistics_json: every statistic the context keeps, as one JSON
// object, so that C, Fortran, Julia and Python callers read them without the C++ structs and a
// new statistic needs no change of any struct (include/cellforce/cellforce.hpp documents the keys).
// The "run" object holds RunStatistics' fields and the MD engine's own counters, which no public
// struct carries.
#include <algorithm>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "api/context_impl.h"

namespace cellforce {

namespace {

nlohmann::json call_json(const Statistics& c) {
  return {{"pipeline_seconds", c.pipeline_seconds},
          {"cell_ids_seconds", c.cell_ids_seconds},
          {"sort_seconds", c.sort_seconds},
          {"collision_cells_seconds", c.collision_cells_seconds},
          {"traversal_seconds", c.traversal_seconds},
          {"accumulate_seconds", c.accumulate_seconds},
          {"transfer_seconds", c.transfer_seconds},
          {"builds", c.builds},
          {"rebuilt", c.rebuilt},
          {"buffer_bytes", c.buffer_bytes}};
}

// The engine's stage times per sampled evaluation.
nlohmann::json stage_json(const MdCounters& c) {
  const double per = c.stage_samples ? 1.0 / double(c.stage_samples) : 0.0;
  return {{"cell_ids", per * (c.stages.t_cell_ids + c.stages.t_count)},
          {"sort", per * c.stages.t_sort},
          {"collision_cells", per * c.stages.t_collision_cells},
          {"traversal", per * c.stages.t_traversal},
          {"accumulate", per * c.stages.t_accumulate},
          {"check", per * c.stages.t_check},
          {"total", per * c.stages.t_total}};
}

// The force engine's buffers and the MD state's arrays that hold any memory, largest first (the
// engine is not const: forces() hands out the force engine it runs).
nlohmann::json memory_json(MdEngine& md) {
  std::vector<std::pair<std::string, std::size_t>> memory;
  for (const auto& [name, bytes] : md.forces().buffers()) memory.emplace_back(name, bytes);
  for (const auto& [name, bytes] : md.state_buffers())
    if (bytes) memory.emplace_back(name, bytes);
  std::stable_sort(memory.begin(), memory.end(), [](const auto& a, const auto& b) { return a.second > b.second; });
  nlohmann::json out = nlohmann::json::array();
  for (const auto& [name, bytes] : memory) out.push_back({{"name", name}, {"bytes", bytes}});
  return out;
}

nlohmann::json run_json(const RunStatistics& r, MdEngine& md) {
  const MdCounters& c = md.counters();
  const PipelineStats& engine = md.forces().stats();
  return {{"steps", r.steps},
          {"evaluations", r.evaluations},
          {"force_seconds", r.force_seconds},
          {"integration_seconds", r.integration_seconds},
          {"step_call_seconds", r.step_call_seconds},
          {"bytes_to_host", r.bytes_to_host},
          {"bytes_to_device", r.bytes_to_device},
          {"stage_samples", c.stage_samples},
          {"stage_seconds", stage_json(c)},
          {"builds", r.builds},
          {"largest_served_displacement", r.largest_served_displacement},
          {"dangerous_builds", r.dangerous_builds},
          {"gated_steps", c.gated_steps},
          {"list_evaluations", c.list_evaluations},
          {"buffer_bytes", r.buffer_bytes},
          {"state_bytes", r.state_bytes},
          {"memory", memory_json(md)},
          {"list_pairs", engine.list_pairs},
          {"list_slots", engine.list_slots},
          {"missed_pairs", r.missed_pairs},
          {"repeated_pairs", r.repeated_pairs},
          {"list_mask_words", engine.list_mask_words},
          {"list_mask_words_held", engine.list_mask_words_held},
          {"graph_builds", c.graph_builds},
          {"list_block", c.list_block},
          {"gate_closings", c.gate_closings},
          {"gate_closings_early", c.gate_closings_early}};
}

}  // namespace

std::string statistics_text(const Context& ctx, const Context::Impl& s) {
  nlohmann::json doc = {{"version", version()}, {"call", call_json(ctx.statistics())}, {"run", nullptr}};
  if (s.md) doc["run"] = run_json(ctx.run_statistics(), *s.md);
  return doc.dump();
}

}  // namespace cellforce
