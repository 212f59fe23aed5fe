// A thin layer over the HDF5 C library: handles that close themselves, and the few reads and
// writes that cellforce's files need (float64 and integer datasets of any rank, scalar and string
// attributes). Every failure becomes a cellforce::Error naming the file and the object; HDF5's
// own error printing is switched off.
#pragma once

#include <hdf5.h>

#include <cstdint>
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
  // True when HDF5 recognises the file (its signature, at offset 0 or after a user block).
  static bool is_hdf5(const std::string& path);

  hid_t id() const { return handle_.get(); }
  const std::string& path() const { return path_; }
  // Flushes and closes; errors surface here rather than in a destructor.
  void close();

 private:
  File(Handle h, std::string path) : handle_(std::move(h)), path_(std::move(path)) {}
  Handle handle_;
  std::string path_;
};

// `where` is the file path, used in error messages. Object paths are HDF5 paths relative to loc.
bool exists(hid_t loc, const std::string& path);
Handle open_group(hid_t loc, const std::string& path, const std::string& where);
Handle create_group(hid_t loc, const std::string& path, const std::string& where);
std::vector<std::string> child_names(hid_t group, const std::string& where);

// Writes a float64 dataset of the given shape (empty shape: a scalar); values.size() must equal
// the product of the shape. Datasets of more than `chunk_threshold` values are chunked and
// deflate-compressed.
void write_doubles(hid_t loc, const std::string& name, const std::vector<double>& values,
                   const std::vector<hsize_t>& shape, const std::string& where);
void write_ints(hid_t loc, const std::string& name, const std::vector<int64_t>& values,
                const std::vector<hsize_t>& shape, const std::string& where);

Array<double> read_doubles(hid_t loc, const std::string& name, const std::string& where);
Array<int64_t> read_ints(hid_t loc, const std::string& name, const std::string& where);

void write_attribute(hid_t obj, const std::string& name, const std::string& value,
                     const std::string& where);
void write_attribute(hid_t obj, const std::string& name, double value, const std::string& where);
void write_attribute(hid_t obj, const std::string& name, int64_t value, const std::string& where);
void write_attribute(hid_t obj, const std::string& name, const std::vector<double>& value,
                     const std::string& where);
void write_attribute(hid_t obj, const std::string& name, const std::vector<std::string>& value,
                     const std::string& where);

bool has_attribute(hid_t obj, const std::string& name);
// Reads a string attribute, scalar or one-dimensional, fixed- or variable-length.
std::vector<std::string> read_string_attribute(hid_t obj, const std::string& name,
                                               const std::string& where);
int64_t read_int_attribute(hid_t obj, const std::string& name, const std::string& where);

}  // namespace cellforce::h5
