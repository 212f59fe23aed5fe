// A thin layer over the HDF5 C library: handles that close themselves, and the few reads and
// writes that cellforce's files need (float64 and integer datasets of any rank, chunked and
// compressed datasets that grow one row at a time for trajectories, hard links, scalar and string
// attributes). Every failure becomes a cellforce::Error naming the file and the object; HDF5's
// own error printing is switched off.
#pragma once

#include <hdf5.h>

#include <cstdint>
#include <functional>
#include <string>
#include <utility>
#include <vector>

namespace cellforce::h5 {

// Owns one HDF5 identifier (file, group, dataset, dataspace, datatype or attribute) and closes it
// with the matching H5?close.
class Handle {
 public:
  Handle() = default;
  explicit Handle(hid_t id) : id_(id) {}
  Handle(Handle&& other) noexcept : id_(std::exchange(other.id_, H5I_INVALID_HID)) {}
  Handle& operator=(Handle&& other) noexcept {
    if (this != &other) {
      reset();
      id_ = std::exchange(other.id_, H5I_INVALID_HID);
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { reset(); }

  hid_t get() const { return id_; }
  bool valid() const { return id_ >= 0; }
  void reset();
  // Gives up ownership: returns the id, which the caller closes, and leaves the handle empty.
  hid_t release() { return std::exchange(id_, H5I_INVALID_HID); }

 private:
  hid_t id_ = H5I_INVALID_HID;
};

// An array read from a dataset: its shape and its values, row-major.
template <class T>
struct Array {
  std::vector<hsize_t> shape;
  std::vector<T> values;
};

class File {
 public:
  // Truncates an existing file; with `exclusive`, fails if the file exists. `where` names the
  // file in errors (the user's path when this one is a temporary).
  static File create(const std::string& path, bool exclusive = false, const std::string& where = {});
  static File open_read(const std::string& path);
  // Opens an existing HDF5 file for reading and writing (a trajectory that a restarted run extends).
  static File open_read_write(const std::string& path);
  // True when HDF5 recognises the file (its signature, at offset 0 or after a user block).
  static bool is_hdf5(const std::string& path);

  hid_t id() const { return handle_.get(); }
  const std::string& path() const { return path_; }
  bool is_open() const { return handle_.valid(); }
  // Writes every buffer to the file (H5Fflush): what was written so far survives the process.
  void flush();
  // Sets aside room for `bytes` more bytes past the file's allocated end (posix_fallocate), so
  // that the writes that use it cannot fail for want of space: a full disk (or a file-size
  // limit) fails here, before anything changes, with the system's reason. trim() gives back what
  // was not used (after a flush: the file then ends where HDF5's allocation ends).
  void reserve(std::uint64_t bytes);
  void trim();
  // Flushes and closes; errors surface here rather than in a destructor.
  void close();

 private:
  File(Handle h, std::string path) : handle_(std::move(h)), path_(std::move(path)) {}
  Handle handle_;
  std::string path_;
};

// Writes a new HDF5 file: `fill(root)` writes its contents into a file created exclusively under a
// fresh temporary name beside `path`, which is renamed to `path` once closed. On any failure the
// temporary is removed and an existing file at `path` is left as it was; errors name `path`.
void write_file_atomically(const std::string& path, const std::function<void(hid_t root)>& fill);

// `where` is the file path, used in error messages. Object paths are HDF5 paths relative to loc.
bool exists(hid_t loc, const std::string& path);
Handle open_group(hid_t loc, const std::string& path, const std::string& where);
Handle create_group(hid_t loc, const std::string& path, const std::string& where);
std::vector<std::string> child_names(hid_t group, const std::string& where);

// Writes a float64 dataset of the given shape (empty shape: a scalar), contiguous and
// uncompressed; values.size() must equal the product of the shape.
void write_doubles(hid_t loc, const std::string& name, const std::vector<double>& values,
                   const std::vector<hsize_t>& shape, const std::string& where);
void write_ints(hid_t loc, const std::string& name, const std::vector<int64_t>& values,
                const std::vector<hsize_t>& shape, const std::string& where);

// How a dataset is stored: contiguous (no chunk shape), or in chunks of `chunk` (one entry per
// axis), compressed with the shuffle and deflate filters at level `deflate` (1-9; 0: no filters)
// where the HDF5 library can deflate (else the chunks are stored uncompressed).
struct Storage {
  std::vector<hsize_t> chunk;
  int deflate = 0;
};
// True when this HDF5 library can write deflate-compressed data.
bool deflate_available();

// A fixed int32 dataset (e.g. species), stored as `storage` says.
void write_int32s(hid_t loc, const std::string& name, const std::vector<int32_t>& values,
                  const std::vector<hsize_t>& shape, const Storage& storage, const std::string& where);

// ---- Datasets that grow one row at a time (trajectories) ----------------------------------------
// Creates an empty dataset of shape [0][row_shape...] of `file_type` (e.g. H5T_IEEE_F64LE) that
// can grow without limit along its first axis; storage.chunk must have one entry per axis.
Handle create_extendible(hid_t loc, const std::string& name, hid_t file_type,
                         const std::vector<hsize_t>& row_shape, const Storage& storage,
                         const std::string& where);
Handle open_dataset(hid_t loc, const std::string& path, const std::string& where);
// The dataset's current shape; with max_shape, also its maximum shape (H5S_UNLIMITED: no limit).
std::vector<hsize_t> dataset_shape(hid_t set, const std::string& where,
                                   std::vector<hsize_t>* max_shape = nullptr);
// Grows or shrinks the first axis to `rows` (H5Dset_extent); shrinking drops the last rows.
void set_rows(hid_t set, hsize_t rows, const std::string& where);
// Writes row `row` (< the current row count) from `values`: the product of the other axes'
// extents, row-major, of `mem_type` (e.g. H5T_NATIVE_DOUBLE).
void write_row(hid_t set, hsize_t row, hid_t mem_type, const void* values, const std::string& where);
// A hard link: `link_path` names the same object as `target` (both relative to loc).
void link_hard(hid_t loc, const std::string& target, const std::string& link_path,
               const std::string& where);
// True when both paths (relative to loc) name the same object, e.g. through a hard link.
bool same_object(hid_t loc, const std::string& a, const std::string& b, const std::string& where);
// The object's path in its file, for messages ("?" when it has none).
std::string object_path(hid_t obj);

Array<double> read_doubles(hid_t loc, const std::string& name, const std::string& where);
Array<int64_t> read_ints(hid_t loc, const std::string& name, const std::string& where);
// One index `row` of the dataset's first axis (one frame of frames x ...), read by a hyperslab
// selection without the other rows; the shape returned lacks the first axis.
Array<double> read_doubles_row(hid_t loc, const std::string& name, hsize_t row, const std::string& where);
// The dataset's shape, without reading it.
std::vector<hsize_t> dataset_shape(hid_t loc, const std::string& name, const std::string& where);

void write_attribute(hid_t obj, const std::string& name, const std::string& value,
                     const std::string& where);
void write_attribute(hid_t obj, const std::string& name, double value, const std::string& where);
void write_attribute(hid_t obj, const std::string& name, int64_t value, const std::string& where);
void write_attribute(hid_t obj, const std::string& name, int32_t value, const std::string& where);
void write_attribute(hid_t obj, const std::string& name, const std::vector<int32_t>& value,
                     const std::string& where);
void write_attribute(hid_t obj, const std::string& name, const std::vector<double>& value,
                     const std::string& where);
void write_attribute(hid_t obj, const std::string& name, const std::vector<std::string>& value,
                     const std::string& where);

// The most bytes of data one attribute may hold here: HDF5 stores an attribute in its object's
// header, whose messages hold at most 64 KiB (65,484 bytes of data with HDF5 1.10; the name, type
// and shape take the rest), and fails only when the attribute is written.
inline constexpr std::size_t kMaxAttributeBytes = 64512;
// The bytes of data of write_fixed_string_attribute's attribute for `values`: each is padded to
// the longest.
std::size_t fixed_strings_bytes(const std::vector<std::string>& values);

// Fixed-length, null-padded strings (ASCII, or UTF-8 when a value needs it), as the H5MD
// specification asks of its string attributes; the other write_attribute overloads for strings
// write variable-length UTF-8. Scalar, or one-dimensional with one entry per value.
void write_fixed_string_attribute(hid_t obj, const std::string& name, const std::string& value,
                                  const std::string& where);
void write_fixed_string_attribute(hid_t obj, const std::string& name,
                                  const std::vector<std::string>& values, const std::string& where);

bool has_attribute(hid_t obj, const std::string& name);
// Reads a string attribute, scalar or one-dimensional, fixed- or variable-length.
std::vector<std::string> read_string_attribute(hid_t obj, const std::string& name,
                                               const std::string& where);
int64_t read_int_attribute(hid_t obj, const std::string& name, const std::string& where);

}  // namespace cellforce::h5
