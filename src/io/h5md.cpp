// Reading one frame of an H5MD file (H5MD 1.x, particles group): positions, box and species.
#include <algorithm>
#include <cmath>
#include <map>

#include "core/error.h"
#include "core/text.h"
#include "io/configuration_file.h"
#include "io/hdf5.h"

namespace cellforce {
namespace {

// A time-dependent H5MD element is a group holding value (frames x ...) and step (frames); a fixed
// one is a plain dataset. Returns the values and shape of the element at the positions' frame:
// the row whose step equals the positions' step (or, without steps, the same row).
h5::Array<double> element_frame(hid_t group, const std::string& name, long frame,
                                const std::vector<double>& position_steps, std::size_t frames,
                                const std::string& where) {
  if (!h5::exists(group, name)) throw Error(where + ": no '" + name + "'");
  H5O_info_t info;
#if H5_VERSION_GE(1, 12, 0)
  const herr_t status = H5Oget_info_by_name3(group, name.c_str(), &info, H5O_INFO_BASIC, H5P_DEFAULT);
#else
  const herr_t status = H5Oget_info_by_name2(group, name.c_str(), &info, H5O_INFO_BASIC, H5P_DEFAULT);
#endif
  if (status < 0) throw Error(where + ": cannot inspect '" + name + "'");
  if (info.type == H5O_TYPE_DATASET) return h5::read_doubles(group, name, where);
  const std::vector<hsize_t> shape = h5::dataset_shape(group, name + "/value", where);
  if (shape.empty()) throw Error(where + ": '" + name + "/value' has no frame axis");
  const std::size_t rows = std::size_t(shape[0]);
  std::size_t row = std::size_t(frame);
  if (!position_steps.empty() && h5::exists(group, name + "/step")) {
    const h5::Array<double> steps = h5::read_doubles(group, name + "/step", where);
    const double want = position_steps[std::size_t(frame)];
    const auto it = std::find(steps.values.begin(), steps.values.end(), want);
    if (it == steps.values.end())
      throw Error(where + ": '" + name + "' has no value at step " + std::to_string((long long)want) +
                  " (the positions' frame " + std::to_string(frame) + ")");
    row = std::size_t(it - steps.values.begin());
  } else if (rows != frames) {
    throw Error(where + ": '" + name + "/value' holds " + std::to_string(rows) + " frames, the positions " +
                std::to_string(frames) + ", and no steps say which belong together");
  }
  if (row >= rows) throw Error(where + ": '" + name + "/step' and '" + name + "/value' disagree in length");
  return h5::read_doubles_row(group, name + "/value", hsize_t(row), where);
}

}  // namespace

ConfigurationFile read_h5md(const std::string& file_name, const ReadOptions& options) {
  h5::File file = h5::File::open_read(file_name);
  const std::string path = display_path(file_name);  // as messages show it
  const hid_t root = file.id();
  if (!h5::exists(root, "particles")) throw Error(path + ": no /particles group (not an H5MD file?)");
  h5::Handle particles = h5::open_group(root, "particles", path);
  const std::vector<std::string> groups = h5::child_names(particles.get(), path);
  std::string name = options.group;
  if (name.empty()) {
    if (groups.size() != 1) {
      std::string list;
      for (const auto& g : groups) list += (list.empty() ? "" : ", ") + g;
      throw Error(path + ": /particles holds " + std::to_string(groups.size()) +
                  " groups (" + list + "); name one");
    }
    name = groups[0];
  }
  const std::string where = path + ": /particles/" + name;
  if (!h5::exists(particles.get(), name)) throw Error(where + ": no such group");
  h5::Handle group = h5::open_group(particles.get(), name, path);

  // Positions: frames x n x dim; only the frame asked for is read.
  const std::vector<hsize_t> pos_shape = h5::dataset_shape(group.get(), "position/value", where);
  if (pos_shape.size() != 3) throw Error(where + "/position/value must be frames x particles x dimension");
  const long frames = long(pos_shape[0]);
  const long frame = options.frame < 0 ? frames + options.frame : options.frame;
  if (frame < 0 || frame >= frames)
    throw Error(where + ": frame " + std::to_string(options.frame) + " requested, the file holds " +
                std::to_string(frames));
  const std::size_t n = std::size_t(pos_shape[1]);
  if (pos_shape[2] > 3) throw Error(where + ": dimension must be 2 or 3, found " + std::to_string(pos_shape[2]));
  const int dim = int(pos_shape[2]);
  std::vector<double> steps;
  if (h5::exists(group.get(), "position/step")) {
    steps = h5::read_doubles(group.get(), "position/step", where).values;
    if (steps.size() != std::size_t(frames))
      throw Error(where + "/position: step holds " + std::to_string(steps.size()) + " values for " +
                  std::to_string(frames) + " frames");
  }

  h5::Handle box = h5::open_group(group.get(), "box", path);
  const int64_t box_dim = h5::read_int_attribute(box.get(), "dimension", where + "/box");
  if (box_dim != dim)
    throw Error(where + "/box: dimension " + std::to_string(box_dim) + " but positions have " +
                std::to_string(dim) + " components");
  if (dim != 2 && dim != 3) throw Error(where + ": dimension must be 2 or 3, found " + std::to_string(dim));
  if (options.dim != 0 && options.dim != dim)
    throw Error(where + ": the file is " + std::to_string(dim) + "D, " + std::to_string(options.dim) + "D was asked for");
  const std::vector<std::string> boundary = h5::read_string_attribute(box.get(), "boundary", where + "/box");
  if (boundary.size() != std::size_t(dim))
    throw Error(where + "/box: boundary names " + std::to_string(boundary.size()) + " axes, dimension is " +
                std::to_string(dim));

  ConfigurationFile out;
  out.source = path + " (/particles/" + name + ", frame " + std::to_string(frame) + ")";
  Box& b = out.config.box;
  b.dim = dim;
  bool any_periodic = false;
  for (int a = 0; a < dim; ++a) {
    if (boundary[std::size_t(a)] == "periodic") b.periodic[a] = any_periodic = true;
    else if (boundary[std::size_t(a)] == "none") b.periodic[a] = false;
    else throw Error(where + "/box: boundary " + quote_excerpt(boundary[std::size_t(a)]) + " is neither 'periodic' nor 'none'");
  }
  for (int a = dim; a < kMaxDim; ++a) {
    b.periodic[a] = false;
    b.length[a] = 0.0;
  }
  if (h5::exists(box.get(), "edges")) {
    // A vector of edge lengths, or a dim x dim matrix of box vectors that must be diagonal.
    const h5::Array<double> edges = element_frame(box.get(), "edges", frame, steps, std::size_t(frames), where + "/box");
    const bool vector = edges.shape.size() == 1 && edges.shape[0] == hsize_t(dim);
    const bool matrix = edges.shape.size() == 2 && edges.shape[0] == hsize_t(dim) && edges.shape[1] == hsize_t(dim);
    if (!vector && !matrix)
      throw Error(where + "/box/edges: expected " + std::to_string(dim) + " lengths or a " + std::to_string(dim) +
                  " x " + std::to_string(dim) + " matrix");
    for (int a = 0; a < dim; ++a)
      for (int c = 0; matrix && c < dim; ++c)
        if (a != c && edges.values[std::size_t(a * dim + c)] != 0.0)
          throw Error(where + "/box/edges: box vector " + std::to_string(a + 1) +
                      " is not along its axis; cellforce supports rectangular boxes only");
    for (int a = 0; a < dim; ++a) {
      const double length = edges.values[std::size_t(matrix ? a * dim + a : a)];
      if (b.periodic[a] && !(length > 0 && std::isfinite(length)))
        throw Error(where + "/box/edges: the periodic axis " + std::string(1, "xyz"[a]) + " has length " +
                    format_number(length));
      // On an open axis the edge only informs; a missing or meaningless one is replaced below.
      b.length[a] = length > 0 && std::isfinite(length) ? length : 0.0;
    }
  } else if (any_periodic) {
    throw Error(where + "/box: periodic axes but no edges");
  }

  out.config.positions = h5::read_doubles_row(group.get(), "position/value", hsize_t(frame), where).values;
  // An open axis without an edge: its length only informs (the particles' extent).
  for (int a = 0; a < dim; ++a) {
    if (b.periodic[a] || b.length[a] > 0) continue;
    double lo = INFINITY, hi = -INFINITY;
    for (std::size_t i = 0; i < n; ++i) {
      lo = std::min(lo, out.config.positions[i * std::size_t(dim) + std::size_t(a)]);
      hi = std::max(hi, out.config.positions[i * std::size_t(dim) + std::size_t(a)]);
    }
    b.length[a] = std::max(1.0, n ? hi - lo : 1.0);
  }

  // Species: integers, fixed or per frame. Named by the species' attribute `names` where it has one
  // (species k is names[k], as cellforce's trajectories store them), else by their decimal value;
  // in order of appearance.
  out.config.types.assign(n, 0);
  if (h5::exists(group.get(), "species")) {
    const h5::Array<double> s = element_frame(group.get(), "species", frame, steps, std::size_t(frames), where);
    if (s.values.size() != n)
      throw Error(where + "/species: " + std::to_string(s.values.size()) + " values for " + std::to_string(n) +
                  " particles");
    std::vector<std::string> names;
    {
      const h5::Handle object(H5Oopen(group.get(), "species", H5P_DEFAULT));
      if (!object.valid()) throw Error(where + ": cannot open 'species'");
      if (h5::has_attribute(object.get(), "names"))
        names = h5::read_string_attribute(object.get(), "names", where + "/species");
    }
    std::map<std::string, uint32_t> index;
    for (std::size_t i = 0; i < n; ++i) {
      const double v = s.values[i];
      if (!(v == std::floor(v) && std::abs(v) < 9.0e15))
        throw Error(where + "/species: particle " + std::to_string(i) + " has species " + format_number(v) +
                    ", not an integer species index");
      if (!names.empty() && !(v >= 0 && v < double(names.size())))
        throw Error(where + "/species: particle " + std::to_string(i) + " has species " + format_number(v) +
                    ", but the attribute names holds " + std::to_string(names.size()) + " names");
      const std::string species = names.empty() ? std::to_string((long long)v) : names[std::size_t(v)];
      auto [it, added] = index.try_emplace(species, uint32_t(out.species.size()));
      if (added) out.species.push_back(species);
      out.config.types[i] = it->second;
    }
  } else {
    out.species = {"0"};
  }
  if (n == 0) out.species.clear();
  return out;
}

ConfigurationFile read_configuration(const std::string& path, const ReadOptions& options) {
  return h5::File::is_hdf5(path) ? read_h5md(path, options) : read_extxyz(path, options);
}

}  // namespace cellforce
