// The pair-list build's arithmetic that needs no device (search/list_build.cu): the column range of a
// row tile's split walk, the rule for the number of splits, the force kernel's block size with the
// next step's kick-drift, the hi-part prefilter's bound, and the fixed-point coordinates the force
// kernel gathers (FixedParticle) with the rule for when it does.
// Plain C++ (CF_HD): the kernels and the tests use the same functions.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "core/grid.h"
#include "core/hd.h"

namespace cellforce::cuda {

// Columns [begin, end) of range `split` of a row tile's `ncols` when they are cut into `splits`
// contiguous ranges of whole 32-column tiles: in order, covering [0, ncols), the last ones possibly
// empty.
struct ColumnRange {
  uint32_t begin, end;
};
CF_HD ColumnRange split_columns(uint32_t ncols, uint32_t splits, uint32_t split) {
  const uint32_t chunk = ((ncols + splits - 1) / splits + 31u) & ~31u;
  const uint32_t begin = split * chunk < ncols ? split * chunk : ncols;
  const uint32_t end = ncols - begin < chunk ? ncols : begin + chunk;
  return {begin, end};
}

// The build's column splits per row tile: a row tile of H occupants walks every occupant of its
// cell (m columns, ~4x the h of a P tile), so with few tiles (a small system: 4,320 at 32,000
// particles in.lj) those long walks are the build's critical path and leave most warp slots idle.
// Each row tile's columns are cut into `splits` ranges (split_columns), one warp each; the fill
// places a range's partners after those of the ranges before it (their counts kept by the count
// pass), so the list is the same, entry for entry, for any number of splits. The rule: the
// smallest power of two up to 8 that gives at least 128 warps per multiprocessor (two waves of 64)
// over the tiles' bound (max_tiles: ~1.9x the tiles there are; the units past them exit at once);
// 4 at 32,000 particles in.lj on the H100, 2 at 64,000, 1 from about 67,000. A rule of the system
// and the device.
inline int build_splits(std::size_t max_tiles, int multiprocessors) {
  const std::size_t wanted = std::size_t(std::max(multiprocessors, 1)) * 128;
  int splits = 1;
  while (splits < 8 && max_tiles * std::size_t(splits) < wanted) splits *= 2;
  return splits;
}

// The list force kernel's threads per particle (1, 2, 4 or 8): enough threads to fill half the
// device (1,024 per multiprocessor), at most 8. A rule of the system and the device.
inline int list_threads_per_particle(std::size_t n, int multiprocessors) {
  const std::size_t wanted = std::size_t(std::max(multiprocessors, 1)) * 1024;
  int threads = 1;
  while (threads < 8 && n * std::size_t(threads) < wanted) threads *= 2;
  return threads;
}

// The threads a block of the force kernel that runs the next step's kick-drift: `narrow`
// (128), or 2 x narrow where the kernel runs one thread a particle (per_particle), narrow blocks
// fill at least one wave (resident[0] blocks a multiprocessor, times the multiprocessors), blocks of
// 2 x narrow (resident[1] a multiprocessor) need no more waves, rounded up, and hold fewer threads a
// multiprocessor. The kernel's blocks all take about as long, and a last wave that leaves
// multiprocessors part idle costs nearly a whole one; with fewer resident threads every wave runs
// faster (the gathers share the L1/TEX pipe with fewer warps). Below one wave, larger blocks would
// leave multiprocessors idle, and at 8 threads a particle (small systems) blocks of 256 run
// slower. On an H100 the in.lj kernel holds 9 blocks of 128 or 4 of 256 (56 registers): a wave is
// 152,064 particles or 135,168, so 256 serves 152,065-270,336, 304,129-405,504, ... and nothing
// above 1,081,344 (1,048,576: 7 waves against 8). A rule of the system and the device.
inline int fused_block_size(std::size_t threads, int per_particle, int narrow, const int (&resident)[2],
                            int multiprocessors) {
  if (per_particle != 1 || resident[0] <= 0 || resident[1] <= 0 || multiprocessors <= 0) return narrow;
  const std::size_t sms = std::size_t(multiprocessors);
  auto waves = [&](std::size_t block, int per_sm) {
    const std::size_t blocks = (threads + block - 1) / block, wave = std::size_t(per_sm) * sms;
    return (blocks + wave - 1) / wave;
  };
  const std::size_t narrow_blocks = (threads + std::size_t(narrow) - 1) / std::size_t(narrow);
  const bool full = narrow_blocks >= std::size_t(resident[0]) * sms;
  const bool fewer = 2 * resident[1] < resident[0];
  const std::size_t wide = 2 * std::size_t(narrow);
  return full && fewer && waves(wide, resident[1]) <= waves(std::size_t(narrow), resident[0]) ? 2 * narrow : narrow;
}

// The hi-part prefilter's bound (list_rows, float coordinates): with staged coordinates at most
// X = max(c/2 + h) from their cell's centre, hi and lo parts of float coordinates (|lo| <= ulp(X)
// / 2), a component of the hi-part difference is within 2 ulp(X) of the compensated one (the lo
// difference, and the rounding of adding it); so the separations differ by at most sqrt(3) x 2
// ulp(X), and with the rounding of both r^2 sums (a few float ulps, FMA or not), hi-part r^2 >=
// (sqrt(out2) + sqrt(3) x 3 ulp(X))^2 (1 + 1e-6) implies the compensated r^2 >= out2. Rounded up to
// float. It assumes what a planned grid gives: every particle within its cells (a grid_override,
// tests only, or particles clamped into an open axis's fallback cell when a coordinate is not
// finite, an evaluation that raises an error anyway, may not); the margin covers coordinates up to
// the next power of two above X.
inline float prefilter_bound(const Grid& g, double out2) {
  double x = 0;
  for (int a = 0; a < g.dim; ++a) x = std::max(x, 0.5 * g.cell[a] + g.half_width);
  const float xf = std::nextafter(float(x), INFINITY);
  const double ulp = double(std::nextafter(xf, INFINITY)) - double(xf);
  const double r = std::sqrt(out2) + std::sqrt(3.0) * 3.0 * ulp;
  return std::nextafter(float(r * r * (1 + 1e-6)), INFINITY);
}

// Fixed-point coordinates (FixedParticle: float pairs, every axis periodic). A coordinate wrapped
// into [0, L) is stored as the integer nearest x / L * 2^32, modulo 2^32 (x rounding up to 2^32
// gives 0, the same point).
CF_HD uint32_t fixed_coordinate(double x, double inv_length) {
  return uint32_t(static_cast<unsigned long long>(rint(x * (inv_length * 0x1p32))));
}
// L / 2^32 as a float pair hi + lo (hi = float(L / 2^32), lo = the rest), so that a separation
// carries no systematic scale error (hi alone would stretch every separation along the axis by up
// to 2^-24 relative: a strained box).
struct FixedScale {
  float hi = 0, lo = 0;
};
// One per axis, as the force kernel takes them (computed once per evaluation on the host).
struct FixedScales {
  FixedScale axis[3];
};
CF_HD FixedScale fixed_scale(double length) {
  const double s = length * 0x1p-32;
  const float hi = float(s);
  return {hi, float(s - double(hi))};
}
// The minimum-image separation a - b along an axis: the difference modulo 2^32 read as a signed
// integer (the image nearest zero, for |a - b| < L / 2), rounded to float and scaled. Its error
// against the double minimum image of the wrapped coordinates: at most L / 2^32 from the two
// quantisations, and two float roundings of |d| (the conversion, the fused scaling).
CF_HD float fixed_separation(uint32_t a, uint32_t b, FixedScale scale) {
  const float f = float(int32_t(a - b));
  return fmaf(f, scale.hi, f * scale.lo);
}

// Whether the force kernel gathers fixed-point positions (float pairs): every axis periodic, and
// every edge at most 2^8 cutoffs, so that the quantisation (at most L / 2^32) is no larger than
// a float rounding of a separation at the cutoff (2^-24 rc): the separation's error stays within
// about two float roundings whatever the box. Larger boxes (and open axes) gather doubles. The
// 100M-particle in.lj box (L = 490, rc = 2.5) is within.
inline bool fixed_point_serves(const Grid& g, double cutoff) {
  for (int a = 0; a < g.dim; ++a)
    if (g.inv_length[a] == 0.0 || !(g.length[a] <= 256.0 * cutoff)) return false;
  return true;
}

// The masks' room a build asks for (`words`: what every unit's masks take), given the device's free
// memory after the old room was given up. Fast (`part` false): words and 1/8 more, where the free
// memory keeps 1/16 of it (at least 512 MiB) to spare after it; otherwise none. Lean (`part`): as
// much of that as the free memory holds with 1/8 of it (at least 2 GiB) and `later_bytes` (what the
// engine may still take) to spare; none where that holds less than 1/16 of the demand. `limit`
// (tests; 0: none) caps it.
struct MaskRoom {
  std::size_t words = 0;  // the room to reserve (0: none)
  bool settled = false;   // lean room granted in part: not asked for again until given up
  bool refused = false;   // less than the demand: a demand this large is not asked for again
};
inline MaskRoom plan_mask_room(std::size_t words, bool part, std::size_t free_bytes, std::size_t limit,
                               std::size_t later_bytes) {
  std::size_t want = words + words / 8;
  if (limit) want = std::min(want, limit);
  MaskRoom room;
  if (part) {
    const std::size_t spare = std::max<std::size_t>(free_bytes / 8, std::size_t(2) << 30) + later_bytes;
    want = std::min(want, free_bytes > spare ? (free_bytes - spare) / sizeof(uint32_t) : 0);
    if (want < words / 16) want = 0;
    room.settled = want < words;
  } else {
    const std::size_t spare = std::max<std::size_t>(free_bytes / 16, std::size_t(512) << 20);
    if (want * sizeof(uint32_t) + spare > free_bytes) want = 0;
  }
  room.words = want;
  room.refused = want < words;
  return room;
}

// The pair list's array for a build whose list takes `entries` slots (padding included) holding
// `pairs` pairs of n particles, with `capacity` slots in the array now and `free_bytes` of device
// memory (the array and the masks' room counted as free: they give way). Declined (the cells serve
// the structure) where the layout holds more than twice the pairs and 64 slots a particle, or where
// a new array would not leave 1/16 of the free memory (at least 512 MiB) to spare. A new array gets
// headroom (1/16 of the entries; 1/64 in lean memory) where the spare is still there twice.
struct ListRoom {
  bool declined = false;
  std::size_t reserve = 0;  // slots to reserve (0: the array holds the list already)
};
inline ListRoom plan_list_room(std::size_t entries, std::size_t pairs, std::size_t n, std::size_t capacity,
                               std::size_t free_bytes, bool lean) {
  ListRoom room;
  const bool held = entries <= capacity;
  const std::size_t spare = std::max<std::size_t>(free_bytes / 16, std::size_t(512) << 20);
  const std::size_t need = entries * sizeof(uint32_t);
  if (entries > 2 * pairs + 64 * n || (!held && need + spare > free_bytes)) {
    room.declined = true;
    return room;
  }
  if (held) return room;
  const std::size_t headroom = entries / (lean ? 64 : 16);
  const bool roomy = need + headroom * sizeof(uint32_t) + 2 * spare <= free_bytes;
  room.reserve = roomy ? entries + headroom : entries;
  return room;
}

}  // namespace cellforce::cuda
