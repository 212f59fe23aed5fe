// The checks a command makes on its output files before it computes or writes anything, so that
// a run is refused at once rather than after its last step, and no file is lost: every output
// must be a file (not a folder) in an existing folder that can be written to; an existing file is
// replaced only when the caller allows it (--overwrite, or a restart continuing its own outputs);
// no two outputs may be the same file, and no output may be one of the inputs. Paths are compared
// as files, not as text: "./a.h5" and "a.h5", a symbolic link and its target, and two hard links
// to one file are the same file.
//
// The checks also claim the outputs for the command: each output's lock file, PATH.cellforce-lock
// beside it (PATH resolved, so every spelling of one file shares one lock), is locked with flock(2) and
// holds the owner's process ID. Two commands started at once on the same output (two processes,
// or two threads of one) cannot both hold it: the second is refused before it writes anything,
// and told which process holds it. The kernel drops a lock when its process dies, so a killed run
// blocks nothing; its lock file is taken over by the next run and removed when that run ends.
// Whether an output exists is decided under its lock, and so is the removal of the temporary files
// that killed writers left beside it (see partial_name).
#pragma once

#include <string>
#include <utility>
#include <vector>

namespace cellforce {

struct InputFile {
  std::string path;
  std::string name;  // how the user gave it, for messages: "the scene file", "[particles] path"
};

struct OutputFile {
  std::string path;
  std::string name;      // how the user gave it, for messages: "--out", "[output] checkpoint"
  bool replace = false;  // an existing file may be replaced (or extended)
};

// The outputs of one command, held from the checks until the claim is destroyed (or released),
// which unlocks and removes their lock files. Movable, not copyable.
class OutputClaim {
 public:
  OutputClaim() = default;
  OutputClaim(OutputClaim&& other) noexcept;
  OutputClaim& operator=(OutputClaim&& other) noexcept;
  OutputClaim(const OutputClaim&) = delete;
  OutputClaim& operator=(const OutputClaim&) = delete;
  ~OutputClaim() { release(); }

  void release();
  // The leftover temporary files of dead writers removed while claiming, for a note.
  const std::vector<std::string>& removed_leftovers() const { return removed_; }

 private:
  friend OutputClaim claim_output_files(const std::vector<OutputFile>&, const std::vector<InputFile>&,
                                        const std::string&, const std::vector<std::pair<std::string, std::string>>&);
  struct Lock {
    std::string output, lock_path;
    int fd = -1;
  };
  std::vector<Lock> locks_;
  std::vector<std::string> removed_;
};

// Checks the outputs and claims them. Throws cellforce::Error naming the path and the option of
// the first problem (every lock taken so far is released again). Outputs with an empty path are
// skipped. `exists_advice` follows the message for an existing file that may not be replaced
// (e.g. "replace it with --overwrite"). An input may equal an output only when both are listed in
// `may_equal` as {input name, output name} (a restart reading the checkpoint it will replace).
[[nodiscard]] OutputClaim claim_output_files(const std::vector<OutputFile>& outputs,
                                             const std::vector<InputFile>& inputs, const std::string& exists_advice,
                                             const std::vector<std::pair<std::string, std::string>>& may_equal = {});

// Whether two paths name the same file (existing or not): their resolved absolute paths (symbolic
// links followed) are equal, or both exist and are one file (hard links).
bool same_file(const std::string& a, const std::string& b);

// A fresh temporary name beside `path` for a file written whole and then renamed to `path`:
// PATH.partial-PID-RANDOM. The writer creates it exclusively (O_EXCL), so that no two writers
// share one. A writer killed before its rename leaves it behind; claiming `path` removes such a
// leftover when its process (PID) is no longer alive, or is this process (which holds the claim and
// so has no write of `path` under way). A live writer's file is never removed.
std::string partial_name(const std::string& path);

// The system's reason for a failed file operation (errno `code`), in words a user acts on: "no space
// left on the device (the disk is full)", the quota, the file-size limit, else strerror's text.
std::string errno_reason(int code);

// The process that holds the claim of `path` (the ID in its lock file), or 0 when no process holds
// it: for messages about a file another run is writing.
long claim_holder(const std::string& path);

}  // namespace cellforce
