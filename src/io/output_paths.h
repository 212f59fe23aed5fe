// The checks a command makes on its output files before it computes or writes anything, so that
// a run is refused at once rather than after its last step, and no file is lost: every output
// must be a file (not a folder) in an existing folder that can be written to; an existing file is
// replaced only when the caller allows it (--overwrite, or a restart continuing its own outputs);
// no two outputs may be the same file, and no output may be one of the inputs. Paths are compared
// as files, not as text: "./a.h5" and "a.h5", a symbolic link and its target, and two hard links
// to one file are the same file.
#pragma once

#include <string>
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

// Throws cellforce::Error naming the path and the option of the first problem. Outputs with an
// empty path are skipped. `exists_advice` follows the message for an existing file that may not
// be replaced (e.g. "replace it with --overwrite"). An input may equal an output only when both
// are listed in `may_equal` as {input name, output name} (a restart reading the checkpoint it
// will replace).
void check_output_files(const std::vector<OutputFile>& outputs, const std::vector<InputFile>& inputs,
                        const std::string& exists_advice,
                        const std::vector<std::pair<std::string, std::string>>& may_equal = {});

// Whether two paths name the same file (existing or not): their resolved absolute paths (symbolic
// links followed) are equal, or both exist and are one file (hard links).
bool same_file(const std::string& a, const std::string& b);

}  // namespace cellforce
