#include "io/output_paths.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
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

std::string in_quotes(const std::string& path) { return "'" + path + "'"; }

// A name of cellforce's own, so that a user's file (NAME.lock, say) is never taken for a lock.
std::string lock_path_of(const std::string& path) { return resolved(path).string() + ".cellforce-lock"; }

// The process ID written in a lock file (0 when it holds none).
long read_pid(int fd) {
  char text[32] = {};
  const ssize_t got = ::pread(fd, text, sizeof text - 1, 0);
  return got > 0 ? std::strtol(text, nullptr, 10) : 0;
}

bool alive(long pid) { return pid > 0 && (::kill(pid_t(pid), 0) == 0 || errno == EPERM); }

// The process ID in a temporary name of `name` (NAME.partial-PID-RANDOM, NAME.partial-PID, or a
// folder probe's NAME.partial-probe-PID-RANDOM); 0 for any other file name.
long partial_pid(const std::string& file, const std::string& name) {
  for (const std::string& prefix : {name + ".partial-probe-", name + ".partial-"}) {
    if (file.compare(0, prefix.size(), prefix) != 0) continue;
    const std::string rest = file.substr(prefix.size());
    std::size_t digits = 0;
    while (digits < rest.size() && rest[digits] >= '0' && rest[digits] <= '9') ++digits;
    if (digits == 0 || digits > 18) return 0;
    const std::string tail = rest.substr(digits);
    bool random_tail = tail.size() > 1 && tail[0] == '-';
    for (std::size_t k = 1; k < tail.size(); ++k) random_tail = random_tail && tail[k] >= '0' && tail[k] <= '9';
    if (!tail.empty() && !random_tail) return 0;
    return std::strtol(rest.substr(0, digits).c_str(), nullptr, 10);
  }
  return 0;
}

// Removes the temporary files of `path` whose writer is dead or is this process; returns them.
std::vector<std::string> remove_leftovers(const std::string& path) {
  std::vector<std::string> removed;
  const fs::path folder = fs::path(path).parent_path();
  const std::string name = fs::path(path).filename().string();
  std::error_code ec;
  for (fs::directory_iterator it(folder.empty() ? fs::path(".") : folder, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string file = it->path().filename().string();
    const long pid = partial_pid(file, name);
    if (pid == 0 || (pid != long(::getpid()) && alive(pid))) continue;
    const fs::path leftover = folder / file;
    std::error_code remove_error;
    if (it->is_regular_file(remove_error) && fs::remove(leftover, remove_error)) removed.push_back(leftover.string());
  }
  return removed;
}

}  // namespace

OutputClaim::OutputClaim(OutputClaim&& other) noexcept
    : locks_(std::move(other.locks_)), removed_(std::move(other.removed_)) {
  other.locks_.clear();
}

OutputClaim& OutputClaim::operator=(OutputClaim&& other) noexcept {
  if (this != &other) {
    release();
    locks_ = std::move(other.locks_);
    removed_ = std::move(other.removed_);
    other.locks_.clear();
  }
  return *this;
}

void OutputClaim::release() {
  // The lock file is removed while still locked: a process that opened it meanwhile and then gets
  // the lock finds it no longer under that name, and takes the new one instead.
  for (Lock& lock : locks_) {
    ::unlink(lock.lock_path.c_str());
    ::close(lock.fd);
  }
  locks_.clear();
}

bool same_file(const std::string& a, const std::string& b) {
  if (resolved(a) == resolved(b)) return true;
  std::error_code ec;
  return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec);
}

std::string partial_name(const std::string& path) {
  static thread_local std::mt19937_64 random{std::random_device{}()};
  return path + ".partial-" + std::to_string(::getpid()) + "-" + std::to_string(random() % 1000000000000ull);
}

std::string errno_reason(int code) {
  if (code == ENOSPC) return "no space left on the device (the disk is full)";
  if (code == EDQUOT) return "the disk quota is exceeded";
  if (code == EFBIG) return "the file is larger than the system allows";
  return std::strerror(code);
}

long claim_holder(const std::string& path) {
  const int fd = ::open(lock_path_of(path).c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return 0;
  long pid = 0;
  if (::flock(fd, LOCK_SH | LOCK_NB) != 0) pid = errno == EWOULDBLOCK ? std::max(read_pid(fd), 1L) : 0;
  ::close(fd);
  return pid;
}

OutputClaim claim_output_files(const std::vector<OutputFile>& outputs, const std::vector<InputFile>& inputs,
                               const std::string& exists_advice,
                               const std::vector<std::pair<std::string, std::string>>& may_equal) {
  OutputClaim claim;
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
    const fs::path folder = fs::path(out.path).parent_path();
    if (!folder.empty() && !fs::is_directory(folder, ec))
      throw Error(out.path + ": its folder " + in_quotes(folder.string()) + " does not exist (" + out.name + ")");

    // The lock file is the folder's test too: every writer here creates a temporary file beside
    // the output and renames it into place.
    OutputClaim::Lock lock{out.path, lock_path_of(out.path), -1};
    for (int attempt = 0;; ++attempt) {
      lock.fd = ::open(lock.lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
      if (lock.fd < 0) {
        const int code = errno;
        throw Error(out.path + ": cannot write in its folder " + in_quotes(folder.empty() ? "." : folder.string()) +
                    " (" + out.name + "): " + errno_reason(code));
      }
      if (::flock(lock.fd, LOCK_EX | LOCK_NB) != 0) {
        const int code = errno;
        long pid = read_pid(lock.fd);
        // The holder writes its ID just after it locks: give it a moment when it has not yet.
        for (int wait = 0; pid == 0 && code == EWOULDBLOCK && wait < 20; ++wait) {
          ::usleep(5000);
          pid = read_pid(lock.fd);
        }
        ::close(lock.fd);
        if (code == EWOULDBLOCK)
          throw Error(out.path + ": in use by another cellforce run (" +
                      (pid > 0 ? "process " + std::to_string(pid) : std::string("another process")) +
                      " holds its lock file " + in_quotes(lock.lock_path) + "; " + out.name +
                      "); wait for that run to end, or write to other files");
        // A file system without locks (ENOLCK, EOPNOTSUPP): the outputs are checked, not claimed,
        // and the lock file goes again unless another run wrote its ID into it.
        if (pid == 0) ::unlink(lock.lock_path.c_str());
        lock.fd = -1;
        break;
      }
      // Locked: still the file under that name (not one its last holder removed meanwhile)?
      struct stat held {}, named {};
      if (::fstat(lock.fd, &held) == 0 && ::stat(lock.lock_path.c_str(), &named) == 0 &&
          held.st_dev == named.st_dev && held.st_ino == named.st_ino)
        break;
      ::close(lock.fd);
      if (attempt == 100) throw Error(out.path + ": cannot lock " + in_quotes(lock.lock_path) + " (" + out.name + ")");
    }
    if (lock.fd >= 0) {
      const std::string pid = std::to_string(::getpid()) + "\n";
      if (::ftruncate(lock.fd, 0) != 0 || ::pwrite(lock.fd, pid.data(), pid.size(), 0) != ssize_t(pid.size())) {
        // The lock holds without the ID; only the message of a refused run loses it.
      }
      claim.locks_.push_back(lock);
    }

    const bool exists = fs::exists(fs::symlink_status(out.path, ec));
    if (exists && !out.replace)
      throw Error(out.path + ": exists (" + out.name + ")" + (exists_advice.empty() ? "" : "; " + exists_advice));
    if (exists && fs::exists(out.path, ec) && !fs::is_regular_file(out.path, ec))
      throw Error(out.path + ": exists and is not a regular file (" + out.name + ")");
    if (lock.fd >= 0)
      for (std::string& removed : remove_leftovers(out.path)) claim.removed_.push_back(std::move(removed));
  }
  return claim;
}

}  // namespace cellforce
