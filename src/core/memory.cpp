#include "core/memory.h"

#include <unistd.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>

namespace cellforce {
namespace {

std::string gigabytes(double bytes) {
  char text[64];
  std::snprintf(text, sizeof text, "%.3g GB", bytes / 1e9);
  return text;
}

std::string count_text(double n) {
  char text[64];
  if (n < 1e18) std::snprintf(text, sizeof text, "%.0f", n);
  else std::snprintf(text, sizeof text, "%.3g", n);
  return text;
}

}  // namespace

std::size_t bytes_per_particle(int dim) {
  const std::size_t slots = std::size_t(1) << dim;
  const std::size_t state = 3 * std::size_t(dim) * sizeof(double) + sizeof(double) + sizeof(uint32_t);
  const std::size_t cells = slots * 2 * (sizeof(uint32_t) + sizeof(uint32_t));
  return state + cells;
}

std::size_t physical_memory() {
  const long pages = ::sysconf(_SC_PHYS_PAGES), page = ::sysconf(_SC_PAGE_SIZE);
  std::size_t have = pages > 0 && page > 0 ? std::size_t(pages) * std::size_t(page) : 0;
  // A container's or batch job's limit (cgroup v2, then v1) when it is lower: "max" or a huge v1
  // value means none.
  for (const char* file : {"/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"}) {
    std::ifstream in(file);
    unsigned long long limit = 0;
    if (in >> limit && limit > 0 && (have == 0 || limit < have)) have = std::size_t(limit);
  }
  return have;
}

void check_particle_count(double n, int dim, const std::string& what) {
  if (!(n <= double(kMaxParticles)))
    throw Error(what + " gives " + count_text(n) + " particles; one evaluation takes at most " +
                std::to_string(kMaxParticles));
  const double per = double(bytes_per_particle(dim));
  const double need = n * per, have = double(physical_memory());
  if (have > 0 && need > have)
    throw Error(what + " gives " + count_text(n) + " particles, which need at least " + gigabytes(need) + " (" +
                std::to_string(std::size_t(per)) + " bytes per particle); the memory available here is " + gigabytes(have));
}

}  // namespace cellforce
