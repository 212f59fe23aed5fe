#include "io/h5md_writer.h"

#include <algorithm>
#include <cmath>
#include <set>
#include <tuple>

#include "core/error.h"
#include "core/text.h"

namespace cellforce {
namespace {

// Largest chunk of a per-particle dataset: HDF5's default chunk cache (1 MiB per dataset) then
// holds a whole chunk, so a reader taking part of a frame decompresses each chunk once.
constexpr std::size_t kChunkBytes = std::size_t(1) << 20;
// Frames per chunk of the small per-frame datasets (step, time, edges, observables): 8 KiB of
// scalars, rewritten in place by each flush until full. Left uncompressed: a compressed chunk
// changes size, and so moves in the file, at every flush.
constexpr hsize_t kSeriesChunk = 1024;
// Deflate level of the per-particle datasets: level 1 saves as much as 4 on coordinates (measured
// on a 32,000-particle liquid: 13% vs 14%) in less time.
constexpr int kDeflate = 1;

const std::string kParticles = std::string("particles/") + H5mdWriter::kGroup;

std::string join(const std::vector<std::string>& values) {
  std::string out;
  for (const std::string& v : values) out += (out.empty() ? "" : ", ") + v;
  return out.empty() ? "none" : out;
}

std::vector<std::string> boundary_names(const Box& box) {
  std::vector<std::string> out;
  for (int a = 0; a < box.dim; ++a) out.push_back(box.periodic[a] ? "periodic" : "none");
  return out;
}

// Particles per chunk: the frame split into equal parts of at most kChunkBytes.
hsize_t particles_per_chunk(std::size_t n, std::size_t bytes_per_particle) {
  const std::size_t most = std::max<std::size_t>(1, kChunkBytes / bytes_per_particle);
  const std::size_t parts = (n + most - 1) / most;
  return hsize_t((n + parts - 1) / parts);
}

void validate(const std::string& path, const Box& box, const std::vector<uint32_t>& species,
              const std::vector<std::string>& species_names, const H5mdOptions& options) {
  if (box.dim != 2 && box.dim != 3)
    throw Error(path + ": the box is " + std::to_string(box.dim) + "-dimensional; trajectories are 2D or 3D");
  for (int a = 0; a < box.dim; ++a)
    if (box.periodic[a] && !(box.length[a] > 0 && std::isfinite(box.length[a])))
      throw Error(path + ": the periodic axis " + std::string(1, "xyz"[a]) + " has length " +
                  std::to_string(box.length[a]));
  if (species.empty()) throw Error(path + ": a trajectory needs at least one particle");
  for (std::size_t i = 0; i < species.size(); ++i)
    if (species[i] >= species_names.size())
      throw Error(path + ": particle " + std::to_string(i) + " has species " + std::to_string(species[i]) +
                  " but " + std::to_string(species_names.size()) + " species names are given");
  for (const std::string& name : species_names)
    if (name.empty()) throw Error(path + ": a species name is empty");
  // The names are one fixed-length string attribute (/particles/all/species names), each padded to
  // the longest: HDF5 would refuse it only after the file was made.
  if (const std::size_t bytes = h5::fixed_strings_bytes(species_names); bytes > h5::kMaxAttributeBytes) {
    const auto longest = std::max_element(species_names.begin(), species_names.end(),
                                          [](const std::string& a, const std::string& b) { return a.size() < b.size(); });
    throw Error(path + ": the species (type) names need an HDF5 attribute of " + std::to_string(bytes) + " bytes (" +
                std::to_string(species_names.size()) + " names padded to the longest, of " +
                std::to_string(longest->size()) + " bytes: " + quote_excerpt(*longest, 24) +
                "); an attribute holds at most " + std::to_string(h5::kMaxAttributeBytes) +
                " bytes: shorten the type names");
  }
  std::set<std::string> seen;
  for (const std::string& name : options.observables) {
    if (name.empty() || name == "." || name == ".." || name.find('/') != std::string::npos)
      throw Error(path + ": '" + name + "' cannot name an observable (non-empty, no '/')");
    if (!seen.insert(name).second) throw Error(path + ": observable '" + name + "' is named twice");
  }
}

}  // namespace

void H5mdWriter::check(const std::string& path, const Box& box, const std::vector<uint32_t>& species,
                       const std::vector<std::string>& species_names, const H5mdOptions& options) {
  validate(path, box, species, species_names, options);
}

H5mdWriter::H5mdWriter(const std::string& path, const Box& box, const std::vector<uint32_t>& species,
                       const std::vector<std::string>& species_names, const H5mdOptions& options)
    : path_(path),
      n_(species.size()),
      dim_(box.dim),
      velocities_(options.velocities),
      forces_(options.forces),
      observables_(options.observables) {
  validate(path, box, species, species_names, options);
  edges_.assign(box.length, box.length + box.dim);
  if (options.append) open_existing(box, species, species_names, options);
  else create(box, species, species_names, options);
}

H5mdWriter::~H5mdWriter() {
  try {
    close();
  } catch (...) {
    // A destructor must not throw; close() reports the error to callers who ask.
  }
}

void H5mdWriter::create(const Box& box, const std::vector<uint32_t>& species,
                        const std::vector<std::string>& species_names, const H5mdOptions& options) {
  const std::string& w = path_;
  file_.emplace(h5::File::create(path_));
  const hid_t root = file_->id();
  {
    h5::Handle h5md = h5::create_group(root, "h5md", w);
    h5::write_attribute(h5md.get(), "version", std::vector<int32_t>{1, 1}, w);
    h5::Handle author = h5::create_group(h5md.get(), "author", w);
    h5::write_fixed_string_attribute(author.get(), "name", options.author, w);
    h5::Handle creator = h5::create_group(h5md.get(), "creator", w);
    h5::write_fixed_string_attribute(creator.get(), "name", "cellforce", w);
    h5::write_fixed_string_attribute(creator.get(), "version",
                                     options.creator_version.empty() ? "unknown" : options.creator_version, w);
  }
  h5::Handle particles = h5::create_group(root, kParticles, w);
  const hsize_t n = n_, dim = hsize_t(dim_);
  const h5::Storage series{{kSeriesChunk}, 0};
  const h5::Storage per_particle{{1, particles_per_chunk(n_, std::size_t(dim_) * sizeof(double)), dim}, kDeflate};

  // position owns step and time; every other time-dependent element links to them (H5MD allows
  // this for elements sampled together, and requires it of box/edges).
  {
    h5::Handle position = h5::create_group(particles.get(), "position", w);
    step_ = h5::create_extendible(position.get(), "step", H5T_STD_I64LE, {}, series, w);
    time_ = h5::create_extendible(position.get(), "time", H5T_IEEE_F64LE, {}, series, w);
    position_ = h5::create_extendible(position.get(), "value", H5T_IEEE_F64LE, {n, dim}, per_particle, w);
  }
  const auto share_step_and_time = [&](const std::string& element) {
    h5::link_hard(root, kParticles + "/position/step", element + "/step", w);
    h5::link_hard(root, kParticles + "/position/time", element + "/time", w);
  };
  {
    h5::Handle box_group = h5::create_group(particles.get(), "box", w);
    h5::write_attribute(box_group.get(), "dimension", int32_t(dim_), w);
    h5::write_fixed_string_attribute(box_group.get(), "boundary", boundary_names(box), w);
    h5::Handle edges = h5::create_group(box_group.get(), "edges", w);
    edges_value_ = h5::create_extendible(edges.get(), "value", H5T_IEEE_F64LE, {dim}, {{kSeriesChunk, dim}, 0}, w);
    share_step_and_time(kParticles + "/box/edges");
  }
  for (const auto& [enabled, name, set] : {std::tuple{velocities_, "velocity", &velocity_},
                                           std::tuple{forces_, "force", &force_}}) {
    if (!enabled) continue;
    h5::Handle element = h5::create_group(particles.get(), name, w);
    *set = h5::create_extendible(element.get(), "value", H5T_IEEE_F64LE, {n, dim}, per_particle, w);
    share_step_and_time(kParticles + "/" + name);
  }
  {
    const std::vector<int32_t> values(species.begin(), species.end());
    h5::write_int32s(particles.get(), "species", values, {n}, {{particles_per_chunk(n_, sizeof(int32_t))}, kDeflate}, w);
    h5::Handle set = h5::open_dataset(particles.get(), "species", w);
    h5::write_fixed_string_attribute(set.get(), "names", species_names, w);
  }
  for (const std::string& name : observables_) {
    const std::string element = "observables/" + name;
    h5::Handle group = h5::create_group(root, element, w);
    observable_values_.push_back(h5::create_extendible(group.get(), "value", H5T_IEEE_F64LE, {}, series, w));
    share_step_and_time(element);
  }
  file_->flush();
}

void H5mdWriter::open_existing(const Box& box, const std::vector<uint32_t>& species,
                               const std::vector<std::string>& species_names, const H5mdOptions& options) {
  const std::string& w = path_;
  const auto refuse = [&](const std::string& why) { throw Error(path_ + ": cannot append to this trajectory: " + why); };
  file_.emplace(h5::File::open_read_write(path_));
  const hid_t root = file_->id();
  if (!h5::exists(root, "h5md") || !h5::exists(root, kParticles + "/position/value"))
    refuse("it has no /h5md or no /" + kParticles + "/position (not written by cellforce)");
  h5::Handle particles = h5::open_group(root, kParticles, w);

  {
    h5::Handle box_group = h5::open_group(particles.get(), "box", w);
    const int64_t dim = h5::read_int_attribute(box_group.get(), "dimension", w + ": /" + kParticles + "/box");
    if (dim != dim_) refuse("the file is " + std::to_string(dim) + "D, this run " + std::to_string(dim_) + "D");
    const std::vector<std::string> boundary =
        h5::read_string_attribute(box_group.get(), "boundary", w + ": /" + kParticles + "/box");
    if (boundary != boundary_names(box))
      refuse("the boundaries differ (file: " + join(boundary) + "; run: " + join(boundary_names(box)) + ")");
  }
  position_ = h5::open_dataset(particles.get(), "position/value", w);
  const std::vector<hsize_t> shape = h5::dataset_shape(position_.get(), w);
  if (shape.size() != 3 || shape[2] != hsize_t(dim_))
    refuse("position/value is not frames x particles x " + std::to_string(dim_));
  if (shape[1] != n_)
    refuse("the file holds " + std::to_string(shape[1]) + " particles, this run " + std::to_string(n_));
  frames_ = std::size_t(shape[0]);

  if (!h5::exists(particles.get(), "species")) refuse("it has no species");
  const std::vector<int64_t> stored = h5::read_ints(particles.get(), "species", w).values;
  if (stored.size() != n_) refuse("species holds " + std::to_string(stored.size()) + " values");
  for (std::size_t i = 0; i < n_; ++i)
    if (stored[i] != int64_t(species[i]))
      refuse("particle " + std::to_string(i) + " has species " + std::to_string(stored[i]) +
             " in the file, " + std::to_string(species[i]) + " in this run");
  {
    h5::Handle set = h5::open_dataset(particles.get(), "species", w);
    const std::vector<std::string> names =
        h5::has_attribute(set.get(), "names") ? h5::read_string_attribute(set.get(), "names", w) : std::vector<std::string>{};
    if (names != species_names)
      refuse("the species names differ (file: " + join(names) + "; run: " + join(species_names) + ")");
  }
  for (const auto& [enabled, name] : {std::pair{options.velocities, "velocity"}, std::pair{options.forces, "force"}}) {
    const bool stored_element = h5::exists(particles.get(), name);
    if (stored_element != enabled)
      refuse(stored_element ? std::string("the file holds ") + name + " values, this run writes none"
                            : std::string("this run writes ") + name + " values, the file holds none");
  }
  {
    std::vector<std::string> stored_names =
        h5::exists(root, "observables") ? h5::child_names(h5::open_group(root, "observables", w).get(), w)
                                        : std::vector<std::string>{};
    std::vector<std::string> run_names = observables_;
    std::sort(stored_names.begin(), stored_names.end());
    std::sort(run_names.begin(), run_names.end());
    if (stored_names != run_names)
      refuse("the observables differ (file: " + join(stored_names) + "; run: " + join(run_names) + ")");
  }

  // Every time-dependent element shares position's step and time and holds as many frames.
  step_ = h5::open_dataset(root, kParticles + "/position/step", w);
  time_ = h5::open_dataset(root, kParticles + "/position/time", w);
  std::vector<std::string> elements = {kParticles + "/box/edges"};
  edges_value_ = h5::open_dataset(root, kParticles + "/box/edges/value", w);
  if (velocities_) {
    velocity_ = h5::open_dataset(root, kParticles + "/velocity/value", w);
    elements.push_back(kParticles + "/velocity");
  }
  if (forces_) {
    force_ = h5::open_dataset(root, kParticles + "/force/value", w);
    elements.push_back(kParticles + "/force");
  }
  for (const std::string& name : observables_) {
    observable_values_.push_back(h5::open_dataset(root, "observables/" + name + "/value", w));
    elements.push_back("observables/" + name);
  }
  for (const std::string& element : elements)
    for (const char* axis : {"step", "time"})
      if (!h5::same_object(root, element + "/" + axis, kParticles + "/position/" + axis, w))
        refuse("/" + element + "/" + axis + " is not a link to /" + kParticles + "/position/" + axis +
               " (not written by cellforce)");
  const std::vector<hsize_t> edges_shape = h5::dataset_shape(edges_value_.get(), w);
  if (edges_shape.size() != 2 || edges_shape[1] != hsize_t(dim_))
    refuse("box/edges/value is not frames x " + std::to_string(dim_));
  // A run that died inside write_frame, or a write that failed and could not be undone, can
  // leave some datasets a frame longer than others: the frames that all of them hold are complete.
  hsize_t shortest = frames_, longest = frames_;
  for (const hid_t set : growing()) {
    std::vector<hsize_t> max_shape;
    const std::vector<hsize_t> set_shape = h5::dataset_shape(set, w, &max_shape);
    if (set_shape.empty() || max_shape[0] != H5S_UNLIMITED) refuse(h5::object_path(set) + " cannot grow");
    shortest = std::min(shortest, set_shape[0]);
    longest = std::max(longest, set_shape[0]);
  }
  if (shortest != longest) {
    for (const hid_t set : growing()) h5::set_rows(set, shortest, w);
    file_->flush();
    dropped_incomplete_ = std::size_t(longest - shortest);
  }
  frames_ = std::size_t(shortest);
  if (frames_ > 0) {
    last_step_ = h5::read_ints(root, kParticles + "/position/step", w).values.back();
    last_time_ = h5::read_doubles(root, kParticles + "/position/time", w).values.back();
  }
}

std::uint64_t H5mdWriter::frame_bytes_bound() const {
  // Per-particle datasets: one frame per chunk, split over particles beyond kChunkBytes; deflate
  // may grow incompressible data by 0.1% and some bytes a chunk. The series datasets write a whole
  // chunk (kSeriesChunk rows) when a frame starts one. The rest covers the chunk indexes' new
  // nodes and the object headers HDF5 may move.
  const std::uint64_t frame = std::uint64_t(n_) * std::uint64_t(dim_) * sizeof(double);
  const std::uint64_t chunks = frame / kChunkBytes + 2;
  const std::uint64_t per_particle = frame + frame / 100 + chunks * 1024;
  const std::uint64_t elements = 1 + (velocities_ ? 1 : 0) + (forces_ ? 1 : 0);
  const std::uint64_t series_row = sizeof(int64_t) + sizeof(double) + std::uint64_t(dim_) * sizeof(double) +
                                   observables_.size() * sizeof(double);
  return elements * per_particle + kSeriesChunk * series_row + (std::uint64_t(256) << 10);
}

std::vector<hid_t> H5mdWriter::growing() const {
  std::vector<hid_t> sets = {step_.get(), time_.get(), position_.get(), edges_value_.get()};
  if (velocities_) sets.push_back(velocity_.get());
  if (forces_) sets.push_back(force_.get());
  for (const h5::Handle& h : observable_values_) sets.push_back(h.get());
  return sets;
}

void H5mdWriter::require_writable() const {
  if (!file_ || !file_->is_open()) throw Error(path_ + ": the H5MD trajectory is closed");
  if (!broken_.empty())
    throw Error(broken_ + "; close the trajectory and reopen it with append, which cuts it back to its complete frames");
}

std::optional<int64_t> H5mdWriter::last_step() const {
  if (frames_ == 0) return std::nullopt;
  return last_step_;
}

void H5mdWriter::write_frame(int64_t step, double time, const double* positions, const double* velocities,
                             const double* forces, const std::vector<double>& observable_values) {
  require_writable();
  // Everything that can be refused is refused before the file changes.
  if (!positions) throw Error(path_ + ": write_frame without positions");
  if (velocities_ && !velocities) throw Error(path_ + ": this trajectory stores velocities; none were given");
  if (forces_ && !forces) throw Error(path_ + ": this trajectory stores forces; none were given");
  if (observable_values.size() != observables_.size())
    throw Error(path_ + ": " + std::to_string(observable_values.size()) + " observable values for " +
                std::to_string(observables_.size()) + " observables (" + join(observables_) + ")");
  if (frames_ > 0 && step <= last_step_)
    throw Error(path_ + ": frame at step " + std::to_string(step) + " refused: the trajectory already holds frames up to step " +
                std::to_string(last_step_) + " (a restarted run must not repeat frames; truncate_after(" +
                std::to_string(step - 1) + ") drops the later ones first)");
  if (std::isnan(time) || (frames_ > 0 && time < last_time_))
    throw Error(path_ + ": frame at step " + std::to_string(step) + " has time " + std::to_string(time) +
                ", before the last stored frame's " + std::to_string(last_time_));

  // Room for the whole frame first: a disk that is full (or would fill during the frame) fails
  // here, before any dataset changes, and the file keeps its frames whole. Without the room, HDF5
  // would fail part way through its writes and leave datasets of unequal length, or a file whose
  // header claims more bytes than were written (unreadable).
  file_->reserve(frame_bytes_bound());
  // Grow every dataset first, then write: a failure part way shrinks them all back, so their
  // lengths never disagree.
  const hsize_t row = frames_;
  const std::vector<hid_t> sets = growing();
  try {
    for (const hid_t set : sets) h5::set_rows(set, row + 1, path_);
    h5::write_row(step_.get(), row, H5T_NATIVE_INT64, &step, path_);
    h5::write_row(time_.get(), row, H5T_NATIVE_DOUBLE, &time, path_);
    h5::write_row(position_.get(), row, H5T_NATIVE_DOUBLE, positions, path_);
    h5::write_row(edges_value_.get(), row, H5T_NATIVE_DOUBLE, edges_.data(), path_);
    if (velocities_) h5::write_row(velocity_.get(), row, H5T_NATIVE_DOUBLE, velocities, path_);
    if (forces_) h5::write_row(force_.get(), row, H5T_NATIVE_DOUBLE, forces, path_);
    for (std::size_t k = 0; k < observables_.size(); ++k)
      h5::write_row(observable_values_[k].get(), row, H5T_NATIVE_DOUBLE, &observable_values[k], path_);
    file_->flush();
    file_->trim();
  } catch (const std::exception& e) {
    // Undo the growth. After a failed write to disk HDF5 may be unable to shrink a dataset whose
    // new chunk it could not store; the writer then refuses further frames, and reopening the
    // file with append cuts every dataset back to the complete frames.
    std::string undo_error;
    for (const hid_t set : sets) {
      try {
        h5::set_rows(set, row, path_);
      } catch (const std::exception& undo) {
        if (undo_error.empty()) undo_error = undo.what();
      }
    }
    H5Fflush(file_->id(), H5F_SCOPE_GLOBAL);
    if (!undo_error.empty())
      broken_ = path_ + ": the failed frame at step " + std::to_string(step) + " could not be undone (" +
                e.what() + "; then " + undo_error + ")";
    throw;
  }
  ++frames_;
  last_step_ = step;
  last_time_ = time;
}

std::vector<int64_t> H5mdWriter::stored_steps(const std::string& path) {
  h5::File file = h5::File::open_read(path);
  const std::string steps = kParticles + "/position/step";
  if (!h5::exists(file.id(), steps)) throw Error(path + ": no /" + steps + " (not a trajectory written by cellforce)");
  std::vector<int64_t> out = h5::read_ints(file.id(), steps, path).values;
  file.close();
  return out;
}

void H5mdWriter::truncate_after(int64_t step) {
  require_writable();
  if (frames_ == 0 || last_step_ <= step) return;
  const hid_t root = file_->id();
  const std::vector<int64_t> steps = h5::read_ints(root, kParticles + "/position/step", path_).values;
  const std::vector<double> times = h5::read_doubles(root, kParticles + "/position/time", path_).values;
  // Steps increase, so the frames to keep are a prefix.
  const hsize_t keep = hsize_t(std::upper_bound(steps.begin(), steps.end(), step) - steps.begin());
  // Shrink every dataset even when one fails, so that they stay equal where they can.
  std::string error;
  for (const hid_t set : growing()) {
    try {
      h5::set_rows(set, keep, path_);
    } catch (const Error& e) {
      if (error.empty()) error = e.what();
    }
  }
  if (!error.empty()) throw Error(path_ + ": truncating the trajectory failed; it may be inconsistent: " + error);
  file_->flush();
  frames_ = std::size_t(keep);
  if (keep > 0) {
    last_step_ = steps[keep - 1];
    last_time_ = times[keep - 1];
  }
}

void H5mdWriter::close() {
  if (!file_) return;
  // Close the datasets first: HDF5 closes a file only when its last object is closed, and the
  // errors of that final close must surface in File::close.
  step_ = h5::Handle();
  time_ = h5::Handle();
  position_ = h5::Handle();
  velocity_ = h5::Handle();
  force_ = h5::Handle();
  edges_value_ = h5::Handle();
  observable_values_.clear();
  std::optional<h5::File> file = std::move(file_);
  file_.reset();
  file->close();
}

}  // namespace cellforce
