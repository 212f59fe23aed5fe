#include "io/output_paths.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <random>

#include "core/error.h"

namespace cellforce {
namespace {

namespace fs = std::filesystem;

// The absolute path with every symbolic link resolved, for a file that may not exist yet: a
// dangling link at the end is followed by hand (weakly_canonical leaves it), the rest by
// weakly_canonical.
fs::path resolved(const std::string& path) {
  std::error_code ec;
  fs::path p = fs::absolute(path, ec);
  for (int hop = 0; hop < 40 && fs::is_symlink(fs::symlink_status(p, ec)); ++hop) {
    const fs::path target = fs::read_symlink(p, ec);
    if (ec) break;
    p = target.is_absolute() ? target : p.parent_path() / target;
  }
  const fs::path canonical = fs::weakly_canonical(p, ec);
  return ec ? p.lexically_normal() : canonical;
}

std::string quoted(const std::string& path) { return "'" + path + "'"; }

// Creates and removes an empty file beside `path`: the folder takes new files (it exists, is a
// folder, is writable, and its file system is not read-only), as every writer here needs (the
// finished file is renamed into place from a temporary beside it).
void probe_folder(const OutputFile& out) {
  const fs::path folder = fs::path(out.path).parent_path();
  std::error_code ec;
  if (!folder.empty() && !fs::is_directory(folder, ec))
    throw Error(out.path + ": its folder " + quoted(folder.string()) + " does not exist (" + out.name + ")");
  const std::string probe =
      out.path + ".partial-probe-" + std::to_string(::getpid()) + "-" + std::to_string(std::random_device{}());
  const int fd = ::open(probe.c_str(), O_WRONLY | O_CREAT | O_EXCL, 0644);
  if (fd < 0) {
    const int code = errno;
    throw Error(out.path + ": cannot write in its folder " + quoted(folder.empty() ? "." : folder.string()) +
                " (" + out.name + "): " + std::strerror(code));
  }
  ::close(fd);
  ::unlink(probe.c_str());
}

}  // namespace

bool same_file(const std::string& a, const std::string& b) {
  if (resolved(a) == resolved(b)) return true;
  std::error_code ec;
  return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec);
}

void check_output_files(const std::vector<OutputFile>& outputs, const std::vector<InputFile>& inputs,
                        const std::string& exists_advice,
                        const std::vector<std::pair<std::string, std::string>>& may_equal) {
  std::vector<const OutputFile*> given;
  for (const OutputFile& out : outputs)
    if (!out.path.empty()) given.push_back(&out);
  for (std::size_t k = 0; k < given.size(); ++k) {
    const OutputFile& out = *given[k];
    std::error_code ec;
    if (fs::is_directory(out.path, ec))
      throw Error(out.path + ": is a folder; " + out.name + " needs a file name");
    for (std::size_t j = 0; j < k; ++j)
      if (same_file(given[j]->path, out.path))
        throw Error(out.path + ": " + given[j]->name + " and " + out.name +
                    " name the same file; each output needs a file of its own");
    for (const InputFile& in : inputs) {
      if (in.path.empty() || !same_file(in.path, out.path)) continue;
      bool allowed = false;
      for (const auto& [input_name, output_name] : may_equal)
        allowed = allowed || (input_name == in.name && output_name == out.name);
      if (!allowed)
        throw Error(out.path + ": " + out.name + " names the input " + in.name + " (" + in.path +
                    "); writing it would destroy the input");
    }
    const bool exists = fs::exists(fs::symlink_status(out.path, ec));
    if (exists && !out.replace)
      throw Error(out.path + ": exists (" + out.name + ")" + (exists_advice.empty() ? "" : "; " + exists_advice));
    if (exists && fs::exists(out.path, ec) && !fs::is_regular_file(out.path, ec))
      throw Error(out.path + ": exists and is not a regular file (" + out.name + ")");
    probe_folder(out);
  }
}

}  // namespace cellforce
