#!/usr/bin/env python3
"""Model behind issue 15's dropped plan to skip tile pairs by bounding box inside a collision cell.

A cell of edge c with its phantom shell of width h = rc / sqrt(2) is filled uniformly at the in.lj
density; occupants are ordered by sub-cell (Morton order on S^3 sub-cells; H and P separately, P
over the extended cell) and cut into tiles of 32, H first. The tile form tests each row tile
against the column tiles its rows pair with (H rows: every occupant; P rows: the H occupants).
Counted: lane tests (32 x column count) with and without skipping tile pairs whose bounding boxes
are at least rc apart, and the interacting pairs from the H side. Cell edges: 5.6 (32,000 particles,
the even-count rule) and 4.41 (1,048,576).

  python3 validation/models/tile_aabb_model.py
"""
import numpy as np

RHO, RC = 0.8442, 2.5
H = RC / np.sqrt(2)


def morton(q, bits):
    code = np.zeros(len(q), dtype=np.int64)
    for b in range(bits):
        for a in range(3):
            code |= ((q[:, a] >> b) & 1).astype(np.int64) << (3 * b + a)
    return code


def cell_cost(c, s, rng, cells=20):
    tested = untested_skip = useful = 0
    for _ in range(cells):
        e = c + 2 * H
        x = rng.uniform(-e / 2, e / 2, (rng.poisson(RHO * e ** 3), 3))
        inside = np.all(np.abs(x) < c / 2, axis=1)

        def order(p, lo, w):
            if s == 1:
                return p
            q = np.clip(((p - lo) / w * s).astype(int), 0, s - 1)
            return p[np.argsort(morton(q, int(np.log2(s))), kind="stable")]

        h_occ, p_occ = order(x[inside], -c / 2, c), order(x[~inside], -e / 2, e)
        occ = np.vstack([h_occ, p_occ])
        nh, m = len(h_occ), len(occ)
        tiles = [occ[i:i + 32] for i in range(0, m, 32)]
        boxes = [(t.min(0), t.max(0)) for t in tiles]
        for ri in range(len(tiles)):
            cols = m if ri * 32 < nh else nh
            for ci in range((cols + 31) // 32):
                lanes = 32 * min(32, cols - ci * 32)
                untested_skip += lanes
                a, b = boxes[ri], boxes[ci]
                gap = np.maximum(0, np.maximum(b[0] - a[1], a[0] - b[1]))
                if (gap ** 2).sum() < RC * RC:
                    tested += lanes
        d = ((h_occ[:, None, :] - occ[None, :, :]) ** 2).sum(-1)
        useful += (d < RC * RC).sum() - nh
    return tested / cells, untested_skip / cells, useful / cells


def main():
    rng = np.random.default_rng(1)
    print("| cell edge | sub-cells per axis | lane tests per cell, skipping | without | saved | interacting (H side) |")
    print("|---|---|---|---|---|---|")
    for c in (5.6, 4.41):
        for s in (1, 2, 4, 8):
            t, t0, u = cell_cost(c, s, rng)
            print(f"| {c} | {s} | {t:,.0f} | {t0:,.0f} | {1 - t / t0:.1%} | {u:,.0f} |")


if __name__ == "__main__":
    main()
