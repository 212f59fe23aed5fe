// Stage 2, sort (GPU Gems 3 ch. 32, sections 32.2.3-32.2.4): the chapter's parallel radix sort on
// the CPU. Per digit: (1) each thread tabulates the digit counts of its contiguous block,
// (2) a prefix sum over (digit, block) gives each block's first output position per digit,
// (3) each block scatters its entries in input order, which makes every pass stable. Only the
// bits the grid needs are sorted; invalid entries (all ones in that window) end up last.
#include <omp.h>

#include <algorithm>

#include "cpu/stages.h"

namespace cellforce::cpu {

void radix_sort(std::vector<uint32_t>& keys, std::vector<uint32_t>& values, int key_bits,
                SortScratch& scratch) {
  constexpr int kDigitBits = 8;
  constexpr std::size_t kRadix = std::size_t(1) << kDigitBits;
  const std::size_t n = keys.size();
  if (n <= 1 || key_bits <= 0) return;
  const int passes = (key_bits + kDigitBits - 1) / kDigitBits;
  const int blocks = std::max(1, std::min(omp_get_max_threads(), int(n / 4096) + 1));
  scratch.keys.resize(n);
  scratch.values.resize(n);
  scratch.counts.assign(kRadix * std::size_t(blocks), 0);
  const uint32_t window = key_bits >= 32 ? 0xffffffffu : (uint32_t(1) << key_bits) - 1;

  uint32_t* src_k = keys.data();
  uint32_t* src_v = values.data();
  uint32_t* dst_k = scratch.keys.data();
  uint32_t* dst_v = scratch.values.data();
  std::size_t* counts = scratch.counts.data();  // counts[digit * blocks + block]
  const std::size_t per_block = (n + blocks - 1) / blocks;

  for (int pass = 0; pass < passes; ++pass) {
    const int shift = pass * kDigitBits;
    auto digit = [&](uint32_t key) { return ((key & window) >> shift) & (kRadix - 1); };
#pragma omp parallel num_threads(blocks)
    {
      // Blocks are fixed by n, not by the threads granted (fewer inside a nested region).
      const int tid = omp_get_thread_num(), nth = omp_get_num_threads();
      for (int b = tid; b < blocks; b += nth) {  // tabulate
        const std::size_t lo = std::min(n, b * per_block), hi = std::min(n, lo + per_block);
        std::size_t local[kRadix] = {};
        for (std::size_t i = lo; i < hi; ++i) ++local[digit(src_k[i])];
        for (std::size_t d = 0; d < kRadix; ++d) counts[d * blocks + b] = local[d];
      }
#pragma omp barrier
#pragma omp single
      {
        std::size_t sum = 0;  // prefix sum in (digit, block) order
        for (std::size_t j = 0; j < kRadix * std::size_t(blocks); ++j) {
          const std::size_t c = counts[j];
          counts[j] = sum;
          sum += c;
        }
      }
      for (int b = tid; b < blocks; b += nth) {  // stable reorder
        const std::size_t lo = std::min(n, b * per_block), hi = std::min(n, lo + per_block);
        std::size_t next[kRadix];
        for (std::size_t d = 0; d < kRadix; ++d) next[d] = counts[d * blocks + b];
        for (std::size_t i = lo; i < hi; ++i) {
          const std::size_t to = next[digit(src_k[i])]++;
          dst_k[to] = src_k[i];
          dst_v[to] = src_v[i];
        }
      }
    }
    std::swap(src_k, dst_k);
    std::swap(src_v, dst_v);
  }
  if (src_k != keys.data()) {  // an odd number of passes left the result in the scratch
    keys.swap(scratch.keys);
    values.swap(scratch.values);
  }
}

}  // namespace cellforce::cpu
