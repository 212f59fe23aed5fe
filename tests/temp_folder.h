// Helpers of the tests that read and write files: a fresh folder per test, the message of the
// cellforce::Error a call throws, and the backends this machine can run.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "core/error.h"

#ifdef CELLFORCE_HAVE_CUDA
#include "engine.h"  // cuda/engine.h
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

// "cpu", and "cuda" where a CUDA device can be used.
inline std::vector<std::string> backends_here() {
  std::vector<std::string> b = {"cpu"};
#ifdef CELLFORCE_HAVE_CUDA
  if (cellforce::GpuEngine::unavailable().empty()) b.push_back("cuda");
#endif
  return b;
}

}  // namespace cftest
