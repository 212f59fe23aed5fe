// Helpers of the tests that read and write files: a fresh folder per test, the message of the
// cellforce::Error a call throws, a file-size limit (a full disk without one), and the backends
// this machine can run.
#pragma once

#include <gtest/gtest.h>
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <stdexcept>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/error.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "backend/engine.h"  // cuda/backend/engine.h
#endif

namespace cftest {

// A fresh folder per test, named after it, removed afterwards.
class TempFolder : public ::testing::Test {
 protected:
  void SetUp() override {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    dir_ = std::filesystem::temp_directory_path() /
           ("cellforce-" + std::to_string(::getpid()) + "-" + info->test_suite_name() + "-" + info->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string path(const std::string& name) const { return (dir_ / name).string(); }
  // Writes `text` to the file `name` in the folder; returns its path.
  std::string write(const std::string& name, const std::string& text) const {
    std::ofstream(path(name)) << text;
    return path(name);
  }
  static std::string read(const std::string& file) {
    std::ifstream in(file);
    std::stringstream s;
    s << in.rdbuf();
    return s.str();
  }

  std::filesystem::path dir_;
};

// The same folder, also the working folder during the test (relative output paths land there).
class WorkingFolder : public TempFolder {
 protected:
  void SetUp() override {
    TempFolder::SetUp();
    previous_ = std::filesystem::current_path();
    std::filesystem::current_path(dir_);
  }
  void TearDown() override {
    std::filesystem::current_path(previous_);
    TempFolder::TearDown();
  }
  std::filesystem::path previous_;
};

// The message of the cellforce::Error that f throws (fails the test when it throws nothing).
template <class F>
std::string error_of(F&& f) {
  try {
    f();
  } catch (const cellforce::Error& e) {
    return e.what();
  }
  ADD_FAILURE() << "no cellforce::Error was thrown";
  return {};
}

// While alive: files of this process cannot grow beyond `bytes` (the soft limit; restored
// afterwards), and a write beyond it fails with EFBIG instead of raising SIGXFSZ (ignored, as
// cellforce's main() ignores it), as a write to a full disk fails with ENOSPC.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) {
    ::getrlimit(RLIMIT_FSIZE, &old_);
    old_handler_ = ::signal(SIGXFSZ, SIG_IGN);
    rlimit limit = old_;
    limit.rlim_cur = bytes < old_.rlim_max ? bytes : old_.rlim_max;
    ok_ = ::setrlimit(RLIMIT_FSIZE, &limit) == 0;
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &old_);
    ::signal(SIGXFSZ, old_handler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;
  bool ok() const { return ok_; }

 private:
  rlimit old_{};
  void (*old_handler_)(int) = nullptr;
  bool ok_ = false;
};

// "cpu", and "cuda" where a CUDA device can be used.
inline std::vector<std::string> backends_here() {
  std::vector<std::string> b = {"cpu"};
#ifdef CELLFORCE_HAVE_CUDA
  if (cellforce::GpuEngine::unavailable().empty()) b.push_back("cuda");
#endif
  return b;
}

// The project folder that holds systems/ (scene files the tests read): $CELLFORCE_DATA_DIR when
// set, else the nearest folder above the test binary or the working directory that has systems/
// and validation/. Nothing of the source tree's location is compiled in, so the binaries run from
// any folder (the GPU machine's copy of the tree included).
inline std::filesystem::path data_dir() {
  namespace fs = std::filesystem;
  if (const char* env = std::getenv("CELLFORCE_DATA_DIR"); env && *env) return fs::path(env);
  std::error_code ec;
  for (fs::path start : {fs::read_symlink("/proc/self/exe", ec).parent_path(), fs::current_path(ec)})
    for (fs::path p = start; !p.empty(); p = p.parent_path()) {
      if (fs::is_directory(p / "systems", ec) && fs::is_directory(p / "validation", ec)) return p;
      if (p == p.parent_path()) break;
    }
  throw std::runtime_error("no folder with systems/ and validation/ above the test binary or the working "
                           "directory: set CELLFORCE_DATA_DIR to the cellforce source folder");
}

// The cellforce program built with the tests: $CELLFORCE_EXE when set, else `cellforce` in the
// test binary's folder or a folder above it (the build folder). Empty when there is none.
inline std::string cellforce_binary() {
  namespace fs = std::filesystem;
  if (const char* env = std::getenv("CELLFORCE_EXE"); env && *env) return env;
  std::error_code ec;
  for (fs::path p = fs::read_symlink("/proc/self/exe", ec).parent_path(); !p.empty(); p = p.parent_path()) {
    if (fs::is_regular_file(p / "cellforce", ec) && ::access((p / "cellforce").c_str(), X_OK) == 0)
      return (p / "cellforce").string();
    if (p == p.parent_path()) break;
  }
  return {};
}

// Starts `program` with `args` in the working folder, its stdout and stderr into the file
// `output`; returns its process ID (waited for with exit_code).
inline pid_t start_program(const std::string& program, const std::vector<std::string>& args,
                           const std::string& output) {
  std::vector<std::string> all = {program};
  all.insert(all.end(), args.begin(), args.end());
  std::vector<char*> argv;
  for (std::string& a : all) argv.push_back(a.data());
  argv.push_back(nullptr);
  const pid_t pid = ::fork();
  if (pid == 0) {  // only async-signal-safe calls until exec
    const int fd = ::open(output.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (fd >= 0) {
      ::dup2(fd, 1);
      ::dup2(fd, 2);
    }
    ::execv(program.c_str(), argv.data());
    ::_exit(127);
  }
  return pid;
}

// The exit code of a started program (128 + the signal when one ended it; -1 when wait fails).
inline int exit_code(pid_t pid) {
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
}

}  // namespace cftest
