// Context::statistics_json and cf_statistics_json: every statistic the context keeps, as one JSON
// object, so that C, Fortran, Julia and Python callers read them without the C++ structs and a
// new statistic needs no change of any struct (include/cellforce/cellforce.hpp documents the keys).
#include <cellforce/cellforce.hpp>

#include <nlohmann/json.hpp>

namespace cellforce {

std::string Context::statistics_json() const {
  const Statistics c = statistics();
  nlohmann::json call = {{"pipeline_seconds", c.pipeline_seconds},
                         {"cell_ids_seconds", c.cell_ids_seconds},
                         {"sort_seconds", c.sort_seconds},
                         {"collision_cells_seconds", c.collision_cells_seconds},
                         {"traversal_seconds", c.traversal_seconds},
                         {"accumulate_seconds", c.accumulate_seconds},
                         {"transfer_seconds", c.transfer_seconds},
                         {"builds", c.builds},
                         {"rebuilt", c.rebuilt},
                         {"buffer_bytes", c.buffer_bytes}};
  nlohmann::json doc = {{"version", version()}, {"call", call}, {"run", nullptr}};
  if (has_state()) {
    const RunStatistics r = run_statistics();
    nlohmann::json memory = nlohmann::json::array();
    for (const auto& [name, bytes] : r.memory) memory.push_back({{"name", name}, {"bytes", bytes}});
    doc["run"] = {{"steps", r.steps},
                  {"evaluations", r.evaluations},
                  {"force_seconds", r.force_seconds},
                  {"integration_seconds", r.integration_seconds},
                  {"step_call_seconds", r.step_call_seconds},
                  {"bytes_to_host", r.bytes_to_host},
                  {"bytes_to_device", r.bytes_to_device},
                  {"stage_samples", r.stage_samples},
                  {"stage_seconds",
                   {{"cell_ids", r.cell_ids},
                    {"sort", r.sort},
                    {"collision_cells", r.collision_cells},
                    {"traversal", r.traversal},
                    {"accumulate", r.accumulate},
                    {"check", r.check},
                    {"total", r.total}}},
                  {"builds", r.builds},
                  {"largest_served_displacement", r.largest_served_displacement},
                  {"dangerous_builds", r.dangerous_builds},
                  {"gated_steps", r.gated_steps},
                  {"list_evaluations", r.list_evaluations},
                  {"buffer_bytes", r.buffer_bytes},
                  {"state_bytes", r.state_bytes},
                  {"memory", memory},
                  {"list_pairs", r.list_pairs},
                  {"list_slots", r.list_slots},
                  {"missed_pairs", r.missed_pairs},
                  {"repeated_pairs", r.repeated_pairs},
                  {"list_mask_words", r.list_mask_words},
                  {"list_mask_words_held", r.list_mask_words_held},
                  {"graph_builds", r.graph_builds},
                  {"list_block", r.list_block},
                  {"gate_closings", r.gate_closings},
                  {"gate_closings_early", r.gate_closings_early}};
  }
  return doc.dump();
}

}  // namespace cellforce
