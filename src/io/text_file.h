// Files written whole or not at all: the bytes go to a temporary file beside `path` (created
// exclusively under a name of its own, see partial_name), which is renamed over it only when every
// byte was written, so that a full disk or a killed process never leaves a half-written file under
// the final name.
#pragma once

#include <cstddef>
#include <string>
#include <vector>

namespace cellforce {

// `what` names the file in errors ("the thermo file"). Throws cellforce::Error with the system's
// reason; the temporary file is removed and an earlier file at `path` is left as it was.
void write_bytes_atomically(const std::string& path, const void* data, std::size_t size, const std::string& what);

// The lines, each ended by a newline, as write_bytes_atomically writes them.
void write_text_atomically(const std::string& path, const std::vector<std::string>& lines, const std::string& what);

}  // namespace cellforce
