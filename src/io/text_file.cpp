#include "io/text_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>

#include "core/error.h"
#include "io/output_paths.h"

namespace cellforce {

void write_bytes_atomically(const std::string& path, const void* data, std::size_t size, const std::string& what) {
  const std::string tmp = partial_name(path);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) {
    const int code = errno;
    throw Error(path + ": cannot write " + what + ": " + errno_reason(code));
  }
  const char* p = static_cast<const char*>(data);
  std::size_t left = size;
  int code = 0;
  while (left > 0) {
    const ssize_t wrote = ::write(fd, p, left);
    if (wrote < 0 && errno == EINTR) continue;
    if (wrote <= 0) {
      code = wrote < 0 ? errno : ENOSPC;
      break;
    }
    p += wrote;
    left -= std::size_t(wrote);
  }
  if (::close(fd) != 0 && code == 0) code = errno;
  if (code != 0) {
    std::remove(tmp.c_str());
    throw Error(path + ": cannot write " + what + ": " + errno_reason(code));
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0) {
    code = errno;
    std::remove(tmp.c_str());
    throw Error(path + ": cannot move " + what + " into place: " + errno_reason(code));
  }
}

void write_text_atomically(const std::string& path, const std::vector<std::string>& lines, const std::string& what) {
  std::string text;
  for (const std::string& line : lines) text.append(line).push_back('\n');
  write_bytes_atomically(path, text.data(), text.size(), what);
}

}  // namespace cellforce
