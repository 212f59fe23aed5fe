#include "io/text_file.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>

#include "core/error.h"

namespace cellforce {

void write_text_atomically(const std::string& path, const std::vector<std::string>& lines, const std::string& what) {
  const std::string tmp = path + ".partial-" + std::to_string(::getpid());
  {
    errno = 0;
    std::ofstream out(tmp, std::ios::trunc);
    for (const std::string& line : lines) out << line << '\n';
    out.flush();
    if (!out) {
      const int code = errno;
      std::remove(tmp.c_str());
      throw Error(path + ": cannot write " + what + (code ? std::string(": ") + std::strerror(code) : ""));
    }
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    std::remove(tmp.c_str());
    throw Error(path + ": cannot move " + what + " into place");
  }
}

}  // namespace cellforce
