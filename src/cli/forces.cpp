#include "cli/forces.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <sstream>

#include <cellforce/cellforce.hpp>

#include "scene/engine_context.h"
#include "cli/options.h"
#include "core/error.h"
#include "core/numbers.h"
#include "core/text.h"
#include "io/configuration_file.h"
#include "io/forces_file.h"
#include "io/output_paths.h"

#ifndef CELLFORCE_VERSION
#define CELLFORCE_VERSION "unknown"
#endif

namespace cellforce {
namespace {

using cli::median;

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream in(s);
  for (std::string part; std::getline(in, part, sep);) out.push_back(part);
  if (!s.empty() && s.back() == sep) out.emplace_back();
  return out;
}

double parse_number(const std::string& text, const std::string& option, const std::string& spec) {
  double v = 0;
  if (const NumberText r = read_real(text, v); r != NumberText::kOk)
    throw Error(option + " " + quote_excerpt(spec) + ": " + real_problem(text, r));
  return v;
}

}  // namespace

ForceField make_force_field(const ForcesArgs& args, const ConfigurationFile& input,
                            std::vector<uint32_t>& type_of_species) {
  ForceField ff;
  ff.cutoff = args.cutoff;
  ff.mode = args.mode;
  ff.mixing = args.mixing;
  ff.types.clear();
  std::map<std::string, std::size_t> index;
  for (const std::string& spec : args.types) {
    const std::vector<std::string> p = split(spec, ':');
    if (p.size() != 3 || p[0].empty())
      throw Error("--type " + spec + ": expected NAME:SIGMA:EPSILON, e.g. A:1.0:1.0");
    if (!index.emplace(p[0], ff.types.size()).second)
      throw Error("--type " + spec + ": type '" + p[0] + "' is given twice");
    ff.types.push_back(ParticleType{p[0], parse_number(p[1], "--type", spec), parse_number(p[2], "--type", spec)});
  }
  if (ff.types.empty()) {
    if (input.species.size() > 1) {
      std::string list;
      for (const auto& s : input.species) list += (list.empty() ? "" : ", ") + quote_excerpt(s);
      throw Error(input.source + " holds species " + list + ": give --type NAME:SIGMA:EPSILON for each");
    }
    const std::string name = input.species.empty() ? "A" : input.species[0];
    ff.types.push_back(ParticleType{name, 1.0, 1.0});
    index.emplace(name, 0);
  }
  std::map<std::pair<std::size_t, std::size_t>, std::string> pair_given;
  for (const std::string& spec : args.pairs) {
    const std::vector<std::string> p = split(spec, ':');
    if (p.size() != 4) throw Error("--pair " + spec + ": expected A:B:SIGMA:EPSILON, e.g. A:B:0.8:1.5");
    for (int k = 0; k < 2; ++k)
      if (!index.count(p[std::size_t(k)]))
        throw Error("--pair " + spec + ": type '" + p[std::size_t(k)] + "' is not given by --type");
    const auto key = std::minmax(index[p[0]], index[p[1]]);
    if (auto [it, added] = pair_given.emplace(key, spec); !added)
      throw Error("--pair " + spec + ": the pair " + p[0] + "-" + p[1] + " is already given by --pair " + it->second);
    ff.overrides.push_back(PairOverride{index[p[0]], index[p[1]], parse_number(p[2], "--pair", spec),
                                        parse_number(p[3], "--pair", spec)});
  }
  type_of_species.assign(input.species.size(), 0);
  for (std::size_t s = 0; s < input.species.size(); ++s) {
    const auto it = index.find(input.species[s]);
    if (it == index.end()) {
      std::size_t first = 0;
      while (input.config.types[first] != s) ++first;
      throw Error(input.source + ": particle " + std::to_string(first) + " has species " +
                  quote_excerpt(input.species[s]) + ", which no --type names");
    }
    type_of_species[s] = uint32_t(it->second);
  }
  ff.validate();
  return ff;
}

int run_forces(const ForcesArgs& args) {
  if (args.out.empty()) throw Error("forces: --out is required");
  if (args.repeats < 1) throw Error("--repeats must be at least 1, got " + std::to_string(args.repeats));
  const OutputClaim claim = claim_output_files({{args.out, "--out", args.overwrite}}, {{args.input, "file"}},
                                               "replace it with --overwrite");
  ConfigurationFile input = read_configuration(args.input, args.read);
  std::vector<uint32_t> type_of_species;
  const ForceField ff = make_force_field(args, input, type_of_species);
  Configuration& config = input.config;
  for (uint32_t& t : config.types) t = type_of_species[t];
  const SystemView sys = config.view();
  // Before any engine is built: bad input names the particle (and the file).
  with_context(input.source, [&] { validate_system(sys, ff); });

  Context ctx = make_context(sys.box, ff, args.engine);
  const std::string precision = args.engine.value(OptionId::kPrecision);
  const int dim = sys.box.dim;
  ForceResult result;
  result.dim = dim;
  result.forces.resize(sys.n * std::size_t(dim));
  result.energies.resize(sys.n);
  double virial[kMaxDim * kMaxDim] = {};
  const Outputs out{result.forces.data(), result.energies.data(), &result.energy, virial};
  std::vector<double> wall, pipeline;
  for (int r = 0; r < args.repeats; ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    with_context(input.source, [&] { ctx.compute(sys.n, sys.positions, sys.types, out); });
    wall.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    pipeline.push_back(ctx.statistics().pipeline_seconds);
  }
  for (int r = 0; r < dim; ++r)
    for (int c = 0; c < dim; ++c) result.virial[r][c] = virial[r * dim + c];
  const PairCounts counts = ctx.count_pairs(sys.n, sys.positions, sys.types);
  const std::string backend = ctx.backend_name(), description = ctx.description();

  std::ostringstream types;  // "A:1:1 B:0.88:0.5 A-B:0.8:1.5", full precision
  types.precision(17);
  for (const ParticleType& t : ff.types)
    types << (&t == ff.types.data() ? "" : " ") << t.name << ':' << t.sigma << ':' << t.epsilon;
  for (const PairOverride& o : ff.overrides)
    types << ' ' << ff.types[o.a].name << '-' << ff.types[o.b].name << ':' << o.sigma << ':' << o.epsilon;
  std::string periodic;  // "T T F", as extended XYZ's pbc
  for (int a = 0; a < sys.box.dim; ++a) periodic += std::string(a ? " " : "") + (sys.box.periodic[a] ? "T" : "F");
  const Attributes attrs = {
      {"backend", backend},
      {"engine", description},
      {"precision", precision},
      {"accumulation", args.engine.value(OptionId::kAccumulation)},
      {"traversal", ctx.traversal()},
      {"sort", ctx.sort()},
      {"cutoff", ff.cutoff},
      {"cutoff_mode", std::string(to_string(ff.mode))},
      {"mixing", std::string(to_string(ff.mixing))},
      {"types", types.str()},
      {"dimension", int64_t(sys.box.dim)},
      {"n_particles", int64_t(sys.n)},
      {"periodic", periodic},
      {"repeats", int64_t(args.repeats)},
      {"evaluation_time", median(wall)},
      {"pipeline_time", median(pipeline)},
      {"pairs_tested", int64_t(counts.tested)},
      {"pairs_within_cutoff", int64_t(counts.within_cutoff)},
      {"input", input.source},
      {"cellforce_version", std::string(CELLFORCE_VERSION)},
  };
  write_forces_file(args.out, result, sys.n, attrs, {{"evaluation_times", wall}});

  if (!args.quiet) {
    double fmax = 0;
    for (std::size_t i = 0; i < sys.n; ++i) {
      double f2 = 0;
      for (int a = 0; a < dim; ++a) f2 += result.forces[i * dim + a] * result.forces[i * dim + a];
      fmax = std::max(fmax, std::sqrt(f2));
    }
    std::printf("cellforce forces: %zu particles, %dD, from %s\n", sys.n, dim, input.source.c_str());
    std::printf("  %s; precision %s; cutoff %g (%s); %zu pairs within the cutoff\n",
                description.c_str(), precision.c_str(), ff.cutoff,
                to_string(ff.mode), counts.within_cutoff);
    std::printf("  energy %.12g (%.9f per particle), max |F| %.6g\n", result.energy,
                sys.n ? result.energy / double(sys.n) : 0.0, fmax);
    std::printf("  time per evaluation, median of %d: %.3f ms (engine pipeline %.3f ms)\n", args.repeats,
                1e3 * median(wall), 1e3 * median(pipeline));
    std::printf("  wrote %s\n", args.out.c_str());
  }
  return 0;
}

}  // namespace cellforce
