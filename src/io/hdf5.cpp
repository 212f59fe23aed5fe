#include "io/hdf5.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <numeric>

#include "core/error.h"
#include "core/memory.h"
#include "core/text.h"
#include "io/output_paths.h"

namespace cellforce::h5 {
namespace {

// HDF5 closes every file still open when the process exits (an atexit handler). A file whose
// H5Fclose failed (the disk filled while its last blocks were written) stays registered half-closed,
// and that handler then crashes inside HDF5 (1.10.8: H5F__close_cb from H5_term_library). cellforce
// closes each file itself, so the handler has nothing to do; it is switched off before HDF5 is
// first used (static initialisation, before main).
const bool kNoAtexit = [] {
  H5dont_atexit();
  return true;
}();

// HDF5 prints its error stack to stderr by default; cellforce reports errors itself.
void quiet() {
  static const bool done = [] {
    H5Eset_auto2(H5E_DEFAULT, nullptr, nullptr);
    return true;
  }();
  (void)done;
  (void)kNoAtexit;
}

[[noreturn]] void fail(const std::string& where, const std::string& what) {
  throw Error(display_path(where) + ": " + what);
}

// The operating system's reason for the HDF5 call that just failed, from HDF5's error stack (its
// POSIX file driver records errno in the message of a failed read, write or truncate: "...,
// errno = 28, error message = 'No space left on device', ..."); empty when the stack names none.
std::string system_reason() {
  int code = 0;
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned, const H5E_error2_t* e, void* data) -> herr_t {
        int& found = *static_cast<int*>(data);
        if (found == 0 && e->desc)
          if (const char* p = std::strstr(e->desc, "errno = ")) found = std::atoi(p + 8);
        return 0;
      },
      &code);
  return code != 0 ? errno_reason(code) : std::string();
}

// The description of the first entry of HDF5's error stack that contains `needle`; empty if none.
std::string stack_entry(const char* needle) {
  struct Search {
    const char* needle;
    std::string found;
  } search{needle, {}};
  H5Ewalk2(
      H5E_DEFAULT, H5E_WALK_DOWNWARD,
      [](unsigned, const H5E_error2_t* e, void* data) -> herr_t {
        Search& s = *static_cast<Search*>(data);
        if (s.found.empty() && e->desc && std::strstr(e->desc, s.needle)) s.found = e->desc;
        return 0;
      },
      &search);
  return search.found;
}

// The number after `key` in `text` ("eof = 1234"), or -1.
long long number_after(const std::string& text, const std::string& key) {
  const std::size_t at = text.find(key);
  return at == std::string::npos ? -1 : std::atoll(text.c_str() + at + key.size());
}

// Why H5Fopen refused an existing HDF5 file, from its error stack: a file cut short, a file that
// another process holds open for writing (HDF5 locks a file while a writer has it open), or the
// system's reason.
std::string open_failure(const std::string& path) {
  const std::string truncated = stack_entry("truncated file");
  if (!truncated.empty()) {
    const long long eof = number_after(truncated, "eof = "), stored = number_after(truncated, "stored_eof = ");
    return "the file is truncated: it holds " + (eof >= 0 ? std::to_string(eof) : std::string("fewer")) +
           " bytes, its header says " + (stored >= 0 ? std::to_string(stored) : std::string("more")) +
           " (a copy or a write that was cut short?)";
  }
  if (!stack_entry("unable to lock").empty() || !stack_entry("lock file").empty()) {
    const long holder = claim_holder(path);
    if (holder > 0)
      return "the file is in use: a running cellforce run (process " + std::to_string(holder) +
             ") is writing it; read it when that run has ended, or read a copy";
    return "the file is locked by another process that has it open for writing (HDF5 file locking); read it "
           "when that process has closed it, or read a copy";
  }
  return system_reason();
}

// fail() for an HDF5 call that returned an error: the system's reason is added when HDF5 names one.
[[noreturn]] void fail_call(const std::string& where, const std::string& what) {
  const std::string reason = system_reason();
  fail(where, reason.empty() ? what : what + ": " + reason);
}

hid_t check(hid_t id, const std::string& where, const std::string& what) {
  if (id < 0) fail_call(where, what);
  return id;
}

void check_status(herr_t status, const std::string& where, const std::string& what) {
  if (status < 0) fail_call(where, what);
}

std::string shape_text(const std::vector<hsize_t>& shape) {
  std::string text;
  for (const hsize_t e : shape) text += (text.empty() ? "" : " x ") + std::to_string(e);
  return shape.empty() ? "scalar" : text;
}

hsize_t element_count(const std::vector<hsize_t>& shape) {
  return std::accumulate(shape.begin(), shape.end(), hsize_t{1}, std::multiplies<>());
}

Handle make_space(const std::vector<hsize_t>& shape, const std::string& where) {
  if (shape.empty()) return Handle(check(H5Screate(H5S_SCALAR), where, "cannot create a dataspace"));
  return Handle(check(H5Screate_simple(int(shape.size()), shape.data(), nullptr), where,
                      "cannot create a dataspace"));
}

template <class T>
void write_dataset(hid_t loc, const std::string& name, hid_t file_type, hid_t mem_type,
                   const std::vector<T>& values, const std::vector<hsize_t>& shape,
                   const std::string& where, hid_t dcpl = H5P_DEFAULT) {
  quiet();
  if (values.size() != element_count(shape))
    fail(where, "dataset '" + name + "': " + std::to_string(values.size()) +
                    " values do not fill its shape");
  Handle space = make_space(shape, where);
  Handle set(check(H5Dcreate2(loc, name.c_str(), file_type, space.get(), H5P_DEFAULT, dcpl,
                              H5P_DEFAULT),
                   where, "cannot create dataset '" + name + "'"));
  if (!values.empty())
    check_status(H5Dwrite(set.get(), mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, values.data()), where,
                 "cannot write dataset '" + name + "'");
}

// Reads a dataset, or with `row` only that index of its first axis (a hyperslab: one frame of a
// frames x ... dataset is read without the others). The size the file declares is checked first:
// a damaged or hostile file that declares 10^12 frames gets a message, not a bad_alloc.
template <class T>
Array<T> read_dataset(hid_t loc, const std::string& name, hid_t mem_type, H5T_class_t want,
                      const std::string& where, const hsize_t* row = nullptr) {
  quiet();
  if (!exists(loc, name)) fail(where, "no dataset '" + name + "'");
  Handle set(check(H5Dopen2(loc, name.c_str(), H5P_DEFAULT), where,
                   "'" + name + "' is not a dataset"));
  Handle type(check(H5Dget_type(set.get()), where, "cannot read the type of '" + name + "'"));
  const H5T_class_t cls = H5Tget_class(type.get());
  if (cls != want && !(want == H5T_FLOAT && cls == H5T_INTEGER))
    fail(where, "dataset '" + name + "' holds " + (cls == H5T_STRING ? "strings" : "another type") +
                    ", expected " + (want == H5T_FLOAT ? "numbers" : "integers"));
  Handle space(check(H5Dget_space(set.get()), where, "cannot read the shape of '" + name + "'"));
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) fail(where, "cannot read the shape of '" + name + "'");
  std::vector<hsize_t> shape(static_cast<std::size_t>(rank));
  if (rank > 0) H5Sget_simple_extent_dims(space.get(), shape.data(), nullptr);
  Array<T> out;
  out.shape = shape;
  std::vector<hsize_t> start(shape.size(), 0), count = shape;
  if (row) {
    if (rank < 1 || *row >= shape[0])
      fail(where, "dataset '" + name + "' has no row " + std::to_string(*row) + " (shape " + shape_text(shape) + ")");
    start[0] = *row;
    count[0] = 1;
    out.shape.erase(out.shape.begin());
  }
  // The bytes asked for, in double (a product of declared extents can exceed any integer).
  double values = 1;
  for (const hsize_t c : count) values *= double(c);
  const double bytes = values * double(sizeof(T)), memory = double(physical_memory());
  if (values > double(std::numeric_limits<std::ptrdiff_t>::max() / sizeof(T)) || (memory > 0 && bytes > memory))
    fail(where, "dataset '" + name + "' declares shape " + shape_text(shape) + ": reading " +
                    (row ? "one row" : "it") + " needs " + format_number(bytes) +
                    " bytes, more than this machine's memory (a damaged file?)");
  out.values = reporting_bad_alloc("reading dataset '" + name + "' of " + where,
                                   [&] { return std::vector<T>(std::size_t(values)); });
  if (out.values.empty()) return out;
  if (!row) {
    check_status(H5Dread(set.get(), mem_type, H5S_ALL, H5S_ALL, H5P_DEFAULT, out.values.data()),
                 where, "cannot read dataset '" + name + "'");
    return out;
  }
  check_status(H5Sselect_hyperslab(space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr),
               where, "cannot select row " + std::to_string(*row) + " of dataset '" + name + "'");
  Handle memspace = make_space(count, where);
  check_status(H5Dread(set.get(), mem_type, memspace.get(), space.get(), H5P_DEFAULT, out.values.data()),
               where, "cannot read row " + std::to_string(*row) + " of dataset '" + name + "'");
  return out;
}

Handle utf8_string_type(const std::string& where) {
  Handle t(check(H5Tcopy(H5T_C_S1), where, "cannot create a string type"));
  check_status(H5Tset_size(t.get(), H5T_VARIABLE), where, "cannot create a string type");
  check_status(H5Tset_cset(t.get(), H5T_CSET_UTF8), where, "cannot create a string type");
  return t;
}

// Chunk shape and filters of a new dataset.
Handle creation_properties(const std::string& name, const Storage& storage, std::size_t rank,
                           const std::string& where) {
  Handle dcpl(check(H5Pcreate(H5P_DATASET_CREATE), where, "cannot create a property list"));
  if (storage.chunk.empty()) return dcpl;
  if (storage.chunk.size() != rank)
    fail(where, "dataset '" + name + "': a chunk shape of rank " + std::to_string(storage.chunk.size()) +
                    " for a dataset of rank " + std::to_string(rank));
  const std::string what = "cannot set the storage of dataset '" + name + "'";
  check_status(H5Pset_chunk(dcpl.get(), int(rank), storage.chunk.data()), where, what);
  if (storage.deflate > 0 && deflate_available()) {
    // Shuffle first: grouping the bytes of equal significance is what lets deflate find the
    // repeated sign, exponent and leading mantissa bytes of floating-point data.
    check_status(H5Pset_shuffle(dcpl.get()), where, what);
    check_status(H5Pset_deflate(dcpl.get(), unsigned(std::min(storage.deflate, 9))), where, what);
  }
  return dcpl;
}

void write_attribute_raw(hid_t obj, const std::string& name, hid_t type, hid_t space,
                         const void* data, const std::string& where) {
  quiet();
  if (H5Aexists(obj, name.c_str()) > 0) H5Adelete(obj, name.c_str());
  Handle attr(check(H5Acreate2(obj, name.c_str(), type, space, H5P_DEFAULT, H5P_DEFAULT), where,
                    "cannot create attribute '" + name + "'"));
  check_status(H5Awrite(attr.get(), type, data), where, "cannot write attribute '" + name + "'");
}

// The length of each fixed-length string: the longest value's (HDF5 has no strings of size 0).
std::size_t fixed_string_size(const std::vector<std::string>& values) {
  std::size_t size = 1;
  for (const std::string& v : values) size = std::max(size, v.size());
  return size;
}

void write_fixed_strings(hid_t obj, const std::string& name, const std::vector<std::string>& values,
                         const std::vector<hsize_t>& shape, const std::string& where) {
  const std::size_t size = fixed_string_size(values);
  if (fixed_strings_bytes(values) > kMaxAttributeBytes)
    fail(where, "attribute '" + name + "' would hold " + std::to_string(fixed_strings_bytes(values)) + " bytes (" +
                    std::to_string(values.size()) + " strings padded to the longest, " + std::to_string(size) +
                    " bytes); an HDF5 attribute holds at most " + std::to_string(kMaxAttributeBytes));
  bool ascii = true;
  for (const std::string& v : values)
    for (const char c : v) ascii = ascii && static_cast<unsigned char>(c) < 0x80;
  Handle type(check(H5Tcopy(H5T_C_S1), where, "cannot create a string type"));
  check_status(H5Tset_size(type.get(), size), where, "cannot create a string type");
  check_status(H5Tset_strpad(type.get(), H5T_STR_NULLPAD), where, "cannot create a string type");
  check_status(H5Tset_cset(type.get(), ascii ? H5T_CSET_ASCII : H5T_CSET_UTF8), where,
               "cannot create a string type");
  std::vector<char> buffer(size * std::max<std::size_t>(values.size(), 1), '\0');
  for (std::size_t k = 0; k < values.size(); ++k)
    std::copy(values[k].begin(), values[k].end(), buffer.begin() + long(k * size));
  Handle space = make_space(shape, where);
  write_attribute_raw(obj, name, type.get(), space.get(), buffer.data(), where);
}

}  // namespace

std::size_t fixed_strings_bytes(const std::vector<std::string>& values) {
  return fixed_string_size(values) * std::max<std::size_t>(values.size(), 1);
}

void Handle::reset() {
  if (id_ < 0) return;
  switch (H5Iget_type(id_)) {
    case H5I_FILE: H5Fclose(id_); break;
    case H5I_GROUP: H5Gclose(id_); break;
    case H5I_DATASET: H5Dclose(id_); break;
    case H5I_DATASPACE: H5Sclose(id_); break;
    case H5I_DATATYPE: H5Tclose(id_); break;
    case H5I_ATTR: H5Aclose(id_); break;
    case H5I_GENPROP_LST: H5Pclose(id_); break;
    default: break;
  }
  id_ = H5I_INVALID_HID;
}

File File::create(const std::string& path, bool exclusive, const std::string& where) {
  quiet();
  const hid_t id = H5Fcreate(path.c_str(), exclusive ? H5F_ACC_EXCL : H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  if (id < 0) {
    const std::string reason = system_reason();
    fail(where.empty() ? path : where,
         "cannot create the HDF5 file" +
             (reason.empty() ? std::string(" (does its folder exist and is it writable?)") : ": " + reason));
  }
  return File(Handle(id), where.empty() ? path : where);
}

File File::open_read(const std::string& path) {
  quiet();
  std::error_code error;  // a name too long to look up is no such file, not an exception
  if (!std::filesystem::exists(path, error)) fail(path, "no such file");
  if (!is_hdf5(path)) fail(path, "not an HDF5 file");
  const hid_t id = H5Fopen(path.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  if (id < 0) {
    const std::string reason = open_failure(path);
    fail(path, "cannot open the HDF5 file" + (reason.empty() ? std::string() : ": " + reason));
  }
  return File(Handle(id), path);
}

File File::open_read_write(const std::string& path) {
  quiet();
  if (!std::filesystem::exists(path)) fail(path, "no such file");
  if (!is_hdf5(path)) fail(path, "not an HDF5 file");
  const hid_t id = H5Fopen(path.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
  if (id < 0) {
    const std::string reason = open_failure(path);
    fail(path, "cannot open the HDF5 file for writing" +
                   (reason.empty() ? std::string(" (is it read-only, or open in another program?)") : ": " + reason));
  }
  return File(Handle(id), path);
}

bool File::is_hdf5(const std::string& path) {
  quiet();
  std::error_code error;
  if (!std::filesystem::is_regular_file(path, error)) return false;
  return H5Fis_hdf5(path.c_str()) > 0;
}

void File::flush() {
  if (!handle_.valid()) fail(path_, "the HDF5 file is closed");
  if (H5Fflush(handle_.get(), H5F_SCOPE_GLOBAL) < 0) fail_call(path_, "cannot write the HDF5 file");
}

namespace {

// The file descriptor of an HDF5 file opened with the default (POSIX) driver; -1 for another.
int descriptor(hid_t file) {
  const Handle fapl(H5Fget_access_plist(file));
  if (!fapl.valid() || H5Pget_driver(fapl.get()) != H5FD_SEC2) return -1;
  void* handle = nullptr;
  if (H5Fget_vfd_handle(file, fapl.get(), &handle) < 0 || !handle) return -1;
  return *static_cast<int*>(handle);
}

}  // namespace

void File::reserve(std::uint64_t bytes) {
  if (!handle_.valid()) fail(path_, "the HDF5 file is closed");
  haddr_t eoa = 0;
  const int fd = descriptor(handle_.get());
  if (fd < 0 || H5Fget_eoa(handle_.get(), &eoa) < 0) return;  // nothing to reserve with
  struct stat st {};
  if (::fstat(fd, &st) != 0) return;
  const off_t end = off_t(eoa + bytes);
  if (end <= st.st_size) return;
  const int code = ::posix_fallocate(fd, st.st_size, end - st.st_size);
  if (code == 0) return;
  if (::ftruncate(fd, st.st_size) != 0) {
    // The file keeps a longer end of zeros, which HDF5 ignores.
  }
  if (code == EOPNOTSUPP || code == ENOSYS || code == EINVAL) return;  // no reservation on this file system
  fail(path_, "cannot write the HDF5 file: " + errno_reason(code));
}

void File::trim() {
  if (!handle_.valid()) return;
  haddr_t eoa = 0;
  const int fd = descriptor(handle_.get());
  struct stat st {};
  if (fd < 0 || H5Fget_eoa(handle_.get(), &eoa) < 0 || ::fstat(fd, &st) != 0 || off_t(eoa) >= st.st_size) return;
  if (::ftruncate(fd, off_t(eoa)) != 0) {
    // The unused room stays at the end of the file, which HDF5 ignores.
  }
}

void File::close() {
  if (!handle_.valid()) return;
  // The handle gives the id up first: after a failed H5Fclose the id must not be closed again (a
  // second H5Fclose of a file whose close failed half-way crashed inside HDF5).
  const hid_t id = handle_.release();
  if (H5Fflush(id, H5F_SCOPE_GLOBAL) < 0) {
    const std::string reason = system_reason();
    H5Fclose(id);  // the file is lost either way; its id is released once
    fail(path_, "cannot write the HDF5 file" + (reason.empty() ? std::string() : ": " + reason));
  }
  check_status(H5Fclose(id), path_, "cannot close the HDF5 file");
}

void write_file_atomically(const std::string& path, const std::function<void(hid_t root)>& fill) {
  // A name no other run uses, created exclusively, so that concurrent runs and a user's own files
  // beside `path` are never overwritten.
  const std::string tmp = partial_name(path);
  try {
    File file = File::create(tmp, /*exclusive=*/true, path);
    fill(file.id());
    file.close();
  } catch (...) {
    std::remove(tmp.c_str());
    throw;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    fail(path, "cannot move the finished file into place");
  }
}

bool exists(hid_t loc, const std::string& path) {
  quiet();
  // H5Lexists fails rather than answering for a path whose parent is missing: walk it.
  std::string prefix;
  std::size_t start = 0;
  while (start <= path.size()) {
    const std::size_t slash = path.find('/', start);
    const std::string part = path.substr(start, slash == std::string::npos ? std::string::npos : slash - start);
    if (!part.empty()) {
      if (!prefix.empty() || path[0] == '/') prefix.push_back('/');
      prefix.append(part);
      if (H5Lexists(loc, prefix.c_str(), H5P_DEFAULT) <= 0) return false;
    }
    if (slash == std::string::npos) break;
    start = slash + 1;
  }
  return true;
}

Handle open_group(hid_t loc, const std::string& path, const std::string& where) {
  quiet();
  if (!exists(loc, path)) fail(where, "no group '" + path + "'");
  return Handle(check(H5Gopen2(loc, path.c_str(), H5P_DEFAULT), where, "'" + path + "' is not a group"));
}

Handle create_group(hid_t loc, const std::string& path, const std::string& where) {
  quiet();
  Handle lcpl(check(H5Pcreate(H5P_LINK_CREATE), where, "cannot create a property list"));
  H5Pset_create_intermediate_group(lcpl.get(), 1);
  return Handle(check(H5Gcreate2(loc, path.c_str(), lcpl.get(), H5P_DEFAULT, H5P_DEFAULT), where,
                      "cannot create group '" + path + "'"));
}

std::vector<std::string> child_names(hid_t group, const std::string& where) {
  quiet();
  H5G_info_t info;
  check_status(H5Gget_info(group, &info), where, "cannot list a group");
  std::vector<std::string> names;
  for (hsize_t k = 0; k < info.nlinks; ++k) {
    const ssize_t len = H5Lget_name_by_idx(group, ".", H5_INDEX_NAME, H5_ITER_INC, k, nullptr, 0, H5P_DEFAULT);
    if (len < 0) fail(where, "cannot list a group");
    std::string name(std::size_t(len) + 1, '\0');
    H5Lget_name_by_idx(group, ".", H5_INDEX_NAME, H5_ITER_INC, k, name.data(), name.size(), H5P_DEFAULT);
    name.resize(std::size_t(len));
    names.push_back(name);
  }
  return names;
}

void write_doubles(hid_t loc, const std::string& name, const std::vector<double>& values,
                   const std::vector<hsize_t>& shape, const std::string& where) {
  write_dataset(loc, name, H5T_IEEE_F64LE, H5T_NATIVE_DOUBLE, values, shape, where);
}

void write_ints(hid_t loc, const std::string& name, const std::vector<int64_t>& values,
                const std::vector<hsize_t>& shape, const std::string& where) {
  write_dataset(loc, name, H5T_STD_I64LE, H5T_NATIVE_INT64, values, shape, where);
}

bool deflate_available() {
  quiet();
  if (H5Zfilter_avail(H5Z_FILTER_DEFLATE) <= 0) return false;
  unsigned config = 0;
  if (H5Zget_filter_info(H5Z_FILTER_DEFLATE, &config) < 0) return false;
  return (config & H5Z_FILTER_CONFIG_ENCODE_ENABLED) != 0;
}

void write_int32s(hid_t loc, const std::string& name, const std::vector<int32_t>& values,
                  const std::vector<hsize_t>& shape, const Storage& storage, const std::string& where) {
  quiet();
  Handle dcpl = creation_properties(name, storage, shape.size(), where);
  write_dataset(loc, name, H5T_STD_I32LE, H5T_NATIVE_INT32, values, shape, where, dcpl.get());
}

Handle create_extendible(hid_t loc, const std::string& name, hid_t file_type,
                         const std::vector<hsize_t>& row_shape, const Storage& storage,
                         const std::string& where) {
  quiet();
  std::vector<hsize_t> shape = {0}, max_shape = {H5S_UNLIMITED};
  shape.insert(shape.end(), row_shape.begin(), row_shape.end());
  max_shape.insert(max_shape.end(), row_shape.begin(), row_shape.end());
  // An extendible dataset must be chunked.
  if (storage.chunk.empty()) fail(where, "dataset '" + name + "': an extendible dataset needs a chunk shape");
  Handle dcpl = creation_properties(name, storage, shape.size(), where);
  Handle space(check(H5Screate_simple(int(shape.size()), shape.data(), max_shape.data()), where,
                     "cannot create a dataspace"));
  return Handle(check(H5Dcreate2(loc, name.c_str(), file_type, space.get(), H5P_DEFAULT, dcpl.get(),
                                 H5P_DEFAULT),
                      where, "cannot create dataset '" + name + "'"));
}

Handle open_dataset(hid_t loc, const std::string& path, const std::string& where) {
  quiet();
  if (!exists(loc, path)) fail(where, "no dataset '" + path + "'");
  return Handle(check(H5Dopen2(loc, path.c_str(), H5P_DEFAULT), where, "'" + path + "' is not a dataset"));
}

std::vector<hsize_t> dataset_shape(hid_t set, const std::string& where, std::vector<hsize_t>* max_shape) {
  quiet();
  const std::string what = "cannot read the shape of '" + object_path(set) + "'";
  Handle space(check(H5Dget_space(set), where, what));
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) fail(where, what);
  const std::size_t axes = std::size_t(rank);
  std::vector<hsize_t> shape(axes), max(axes);
  if (rank > 0) check_status(H5Sget_simple_extent_dims(space.get(), shape.data(), max.data()), where, what);
  if (max_shape) *max_shape = max;
  return shape;
}

void set_rows(hid_t set, hsize_t rows, const std::string& where) {
  quiet();
  std::vector<hsize_t> shape = dataset_shape(set, where);
  const std::string name = object_path(set);
  if (shape.empty()) fail(where, "'" + name + "' is a scalar; it has no rows");
  shape[0] = rows;
  check_status(H5Dset_extent(set, shape.data()), where, "cannot resize '" + name + "' to " + std::to_string(rows) + " rows");
}

void write_row(hid_t set, hsize_t row, hid_t mem_type, const void* values, const std::string& where) {
  quiet();
  const std::string name = object_path(set);
  const std::vector<hsize_t> shape = dataset_shape(set, where);
  if (shape.empty() || row >= shape[0])
    fail(where, "'" + name + "' has no row " + std::to_string(row));
  std::vector<hsize_t> start(shape.size(), 0), count = shape;
  start[0] = row;
  count[0] = 1;
  Handle file_space(check(H5Dget_space(set), where, "cannot read the shape of '" + name + "'"));
  check_status(H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(), nullptr),
               where, "cannot select row " + std::to_string(row) + " of '" + name + "'");
  Handle mem_space(check(H5Screate_simple(int(count.size()), count.data(), nullptr), where,
                         "cannot create a dataspace"));
  check_status(H5Dwrite(set, mem_type, mem_space.get(), file_space.get(), H5P_DEFAULT, values), where,
               "cannot write row " + std::to_string(row) + " of '" + name + "'");
}

void link_hard(hid_t loc, const std::string& target, const std::string& link_path, const std::string& where) {
  quiet();
  check_status(H5Lcreate_hard(loc, target.c_str(), loc, link_path.c_str(), H5P_DEFAULT, H5P_DEFAULT), where,
               "cannot link '" + link_path + "' to '" + target + "'");
}

bool same_object(hid_t loc, const std::string& a, const std::string& b, const std::string& where) {
  quiet();
  if (!exists(loc, a) || !exists(loc, b)) return false;
  H5O_info_t ia, ib;
#if H5_VERSION_GE(1, 12, 0)
  check_status(H5Oget_info_by_name3(loc, a.c_str(), &ia, H5O_INFO_BASIC, H5P_DEFAULT), where, "cannot inspect '" + a + "'");
  check_status(H5Oget_info_by_name3(loc, b.c_str(), &ib, H5O_INFO_BASIC, H5P_DEFAULT), where, "cannot inspect '" + b + "'");
  int cmp = 1;
  check_status(H5Otoken_cmp(loc, &ia.token, &ib.token, &cmp), where, "cannot compare '" + a + "' and '" + b + "'");
  return ia.fileno == ib.fileno && cmp == 0;
#else
  check_status(H5Oget_info_by_name2(loc, a.c_str(), &ia, H5O_INFO_BASIC, H5P_DEFAULT), where, "cannot inspect '" + a + "'");
  check_status(H5Oget_info_by_name2(loc, b.c_str(), &ib, H5O_INFO_BASIC, H5P_DEFAULT), where, "cannot inspect '" + b + "'");
  return ia.fileno == ib.fileno && ia.addr == ib.addr;
#endif
}

std::string object_path(hid_t obj) {
  quiet();
  const ssize_t len = H5Iget_name(obj, nullptr, 0);
  if (len <= 0) return "?";
  std::string name(std::size_t(len) + 1, '\0');
  H5Iget_name(obj, name.data(), name.size());
  name.resize(std::size_t(len));
  return name;
}

Array<double> read_doubles(hid_t loc, const std::string& name, const std::string& where) {
  return read_dataset<double>(loc, name, H5T_NATIVE_DOUBLE, H5T_FLOAT, where);
}

Array<int64_t> read_ints(hid_t loc, const std::string& name, const std::string& where) {
  return read_dataset<int64_t>(loc, name, H5T_NATIVE_INT64, H5T_INTEGER, where);
}

Array<double> read_doubles_row(hid_t loc, const std::string& name, hsize_t row, const std::string& where) {
  return read_dataset<double>(loc, name, H5T_NATIVE_DOUBLE, H5T_FLOAT, where, &row);
}

std::vector<hsize_t> dataset_shape(hid_t loc, const std::string& name, const std::string& where) {
  quiet();
  if (!exists(loc, name)) fail(where, "no dataset '" + name + "'");
  Handle set(check(H5Dopen2(loc, name.c_str(), H5P_DEFAULT), where, "'" + name + "' is not a dataset"));
  Handle space(check(H5Dget_space(set.get()), where, "cannot read the shape of '" + name + "'"));
  const int rank = H5Sget_simple_extent_ndims(space.get());
  if (rank < 0) fail(where, "cannot read the shape of '" + name + "'");
  std::vector<hsize_t> shape(static_cast<std::size_t>(rank));
  if (rank > 0) H5Sget_simple_extent_dims(space.get(), shape.data(), nullptr);
  return shape;
}

void write_attribute(hid_t obj, const std::string& name, const std::string& value,
                     const std::string& where) {
  Handle type = utf8_string_type(where);
  Handle space = make_space({}, where);
  const char* p = value.c_str();
  write_attribute_raw(obj, name, type.get(), space.get(), &p, where);
}

void write_attribute(hid_t obj, const std::string& name, double value, const std::string& where) {
  Handle space = make_space({}, where);
  write_attribute_raw(obj, name, H5T_NATIVE_DOUBLE, space.get(), &value, where);
}

void write_attribute(hid_t obj, const std::string& name, int64_t value, const std::string& where) {
  Handle space = make_space({}, where);
  write_attribute_raw(obj, name, H5T_NATIVE_INT64, space.get(), &value, where);
}

void write_attribute(hid_t obj, const std::string& name, int32_t value, const std::string& where) {
  Handle space = make_space({}, where);
  write_attribute_raw(obj, name, H5T_NATIVE_INT32, space.get(), &value, where);
}

void write_attribute(hid_t obj, const std::string& name, const std::vector<int32_t>& value,
                     const std::string& where) {
  Handle space = make_space({hsize_t(value.size())}, where);
  write_attribute_raw(obj, name, H5T_NATIVE_INT32, space.get(), value.data(), where);
}

void write_attribute(hid_t obj, const std::string& name, const std::vector<double>& value,
                     const std::string& where) {
  Handle space = make_space({hsize_t(value.size())}, where);
  write_attribute_raw(obj, name, H5T_NATIVE_DOUBLE, space.get(), value.data(), where);
}

void write_attribute(hid_t obj, const std::string& name, const std::vector<std::string>& value,
                     const std::string& where) {
  Handle type = utf8_string_type(where);
  Handle space = make_space({hsize_t(value.size())}, where);
  std::vector<const char*> p;
  for (const std::string& s : value) p.push_back(s.c_str());
  write_attribute_raw(obj, name, type.get(), space.get(), p.data(), where);
}

void write_fixed_string_attribute(hid_t obj, const std::string& name, const std::string& value,
                                  const std::string& where) {
  write_fixed_strings(obj, name, {value}, {}, where);
}

void write_fixed_string_attribute(hid_t obj, const std::string& name,
                                  const std::vector<std::string>& values, const std::string& where) {
  write_fixed_strings(obj, name, values, {hsize_t(values.size())}, where);
}

bool has_attribute(hid_t obj, const std::string& name) {
  quiet();
  return H5Aexists(obj, name.c_str()) > 0;
}

std::vector<std::string> read_string_attribute(hid_t obj, const std::string& name,
                                               const std::string& where) {
  quiet();
  if (!has_attribute(obj, name)) fail(where, "no attribute '" + name + "'");
  Handle attr(check(H5Aopen(obj, name.c_str(), H5P_DEFAULT), where, "cannot open attribute '" + name + "'"));
  Handle type(check(H5Aget_type(attr.get()), where, "cannot read attribute '" + name + "'"));
  if (H5Tget_class(type.get()) != H5T_STRING) fail(where, "attribute '" + name + "' is not a string");
  Handle space(check(H5Aget_space(attr.get()), where, "cannot read attribute '" + name + "'"));
  const hssize_t count = H5Sget_simple_extent_npoints(space.get());
  if (count < 0) fail(where, "cannot read attribute '" + name + "'");
  std::vector<std::string> out;
  Handle mem(check(H5Tcopy(type.get()), where, "cannot read attribute '" + name + "'"));
  if (H5Tis_variable_str(type.get()) > 0) {
    std::vector<char*> p(std::size_t(count), nullptr);
    check_status(H5Aread(attr.get(), mem.get(), p.data()), where, "cannot read attribute '" + name + "'");
    for (char* s : p) out.emplace_back(s ? s : "");
#if H5_VERSION_GE(1, 12, 0)
    H5Treclaim(mem.get(), space.get(), H5P_DEFAULT, p.data());
#else
    H5Dvlen_reclaim(mem.get(), space.get(), H5P_DEFAULT, p.data());
#endif
  } else {
    const std::size_t size = H5Tget_size(type.get());
    std::vector<char> buf(std::size_t(count) * size);
    check_status(H5Aread(attr.get(), mem.get(), buf.data()), where, "cannot read attribute '" + name + "'");
    for (hssize_t k = 0; k < count; ++k) {
      std::string s(buf.data() + std::size_t(k) * size, size);
      s.resize(std::min(s.find('\0'), s.size()));
      while (!s.empty() && s.back() == ' ') s.pop_back();  // space-padded strings
      out.push_back(s);
    }
  }
  return out;
}

int64_t read_int_attribute(hid_t obj, const std::string& name, const std::string& where) {
  quiet();
  if (!has_attribute(obj, name)) fail(where, "no attribute '" + name + "'");
  Handle attr(check(H5Aopen(obj, name.c_str(), H5P_DEFAULT), where, "cannot open attribute '" + name + "'"));
  Handle type(check(H5Aget_type(attr.get()), where, "cannot read attribute '" + name + "'"));
  Handle space(check(H5Aget_space(attr.get()), where, "cannot read attribute '" + name + "'"));
  if (H5Tget_class(type.get()) != H5T_INTEGER || H5Sget_simple_extent_npoints(space.get()) != 1)
    fail(where, "attribute '" + name + "' is not one integer");
  int64_t value = 0;
  check_status(H5Aread(attr.get(), H5T_NATIVE_INT64, &value), where, "cannot read attribute '" + name + "'");
  return value;
}

}  // namespace cellforce::h5
