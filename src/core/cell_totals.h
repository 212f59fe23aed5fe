// What the traversal (stage 4) sums per collision cell besides the forces, written once for the
// CPU loop and the CUDA kernels: the pair energies and the virial, and how the virial's six
// components are laid out. Per-cell totals are summed over the cells afterwards in a fixed order,
// so the result does not depend on the thread mapping.
#pragma once

#include <type_traits>

#include "core/grid.h"
#include "core/hd.h"

namespace cellforce {

// The virial's components in the order the engines keep them: xx, yy, zz, xy, xz, yz (2D uses
// xx, yy, xy); component k is the symmetric pair (virial_row(k), virial_col(k)).
inline constexpr int kVirialComponents = 6;
CF_HD constexpr int virial_row(int k) { return k < 3 ? k : (k == 5 ? 1 : 0); }
CF_HD constexpr int virial_col(int k) { return k < 3 ? k : (k == 3 ? 1 : 2); }

// Per cell: [0] the pair-energy sum, [1 + k] virial component k (sum over pairs of r_a f_b).
inline constexpr int kCellTotals = 1 + kVirialComponents;

// A cell's totals, accumulated pair by pair. With float sums (single precision) the pairs are
// summed in blocks of kBlock, each block then added to the total: a crowded cell of n pairs then
// rounds ~kBlock + n/kBlock times per term instead of ~n times. finish() must run before v is
// read. Energy and Virial leave their terms out at compile time.
template <class Accum, bool Energy, bool Virial>
struct CellTotals {
  static constexpr bool kBlocked = std::is_same_v<Accum, float> && (Energy || Virial);
  static constexpr int kBlock = 64;
  Accum v[kCellTotals] = {};
  Accum block[kBlocked ? kCellTotals : 1] = {};
  int in_block = 0;

  // One pair at separation d (D components) with pair energy e and F(r)/r = fr.
  template <int D, class Real>
  CF_HD void add(Real e, Real fr, const Real* d) {
    Accum* s = kBlocked ? block : v;
    if constexpr (Energy) s[0] += Accum(e);
    if constexpr (Virial) {
      s[1] += Accum(fr * d[0] * d[0]);
      s[2] += Accum(fr * d[1] * d[1]);
      s[4] += Accum(fr * d[0] * d[1]);
      if constexpr (D == 3) {
        s[3] += Accum(fr * d[2] * d[2]);
        s[5] += Accum(fr * d[0] * d[2]);
        s[6] += Accum(fr * d[1] * d[2]);
      }
    }
    if constexpr (kBlocked)
      if (++in_block == kBlock) finish();
  }

  CF_HD void finish() {
    if constexpr (kBlocked) {
      for (int k = 0; k < kCellTotals; ++k) {
        v[k] += block[k];
        block[k] = 0;
      }
      in_block = 0;
    }
  }
};

// Per-axis lengths for the pair loop's minimum image: nonzero only where one cell spans a
// periodic axis (elsewhere the staged coordinates need no wrap, and zero leaves them untouched).
template <class Real>
CF_HD void wrap_lengths(const Grid& g, Real length[kMaxDim], Real inv_length[kMaxDim]) {
  for (int a = 0; a < kMaxDim; ++a) {
    const bool w = a < g.dim && g.wraps_inside_cell(a);
    length[a] = w ? Real(g.length[a]) : Real(0);
    inv_length[a] = w ? Real(g.inv_length[a]) : Real(0);
  }
}

}  // namespace cellforce
