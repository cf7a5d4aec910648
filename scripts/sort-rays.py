#!/usr/bin/python3
"""Reorders a .rays file (docs/RAYSETS.md) so that rays that would walk together are neighbours:

    /usr/bin/python3 scripts/sort-rays.py IN.rays OUT.rays [--block N] [--key KEY]

Within each block of N consecutive rays (default: the whole set) the rays are sorted by KEY:
  octant-origin  the direction's octant, then the origin's Morton code (default)
  origin         the origin's Morton code
  direction      the unit direction's Morton code
  dir-origin     a coarse direction (its Morton code's top 15 bits), then the origin's Morton code
Morton codes take 10 bits an axis of the origin in the rays' bounding box, or of the unit
direction in [-1, 1]^3. The sort is stable; OUT holds the same rays in the new order, so every
tool traces exactly the same rays (`kdgrid bench --rays-dir`). Needs numpy (python3-numpy).
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import rays_file  # noqa: E402


def spread10(x):
    """The 10 low bits of x spread to every third bit."""
    x = x & 0x3FF
    x = (x | (x << 16)) & 0x30000FF
    x = (x | (x << 8)) & 0x300F00F
    x = (x | (x << 4)) & 0x30C30C3
    x = (x | (x << 2)) & 0x9249249
    return x


def morton(q):
    return spread10(q[:, 0]) | (spread10(q[:, 1]) << 1) | (spread10(q[:, 2]) << 2)


def quantize(v, lo, hi):
    return np.clip(((v - lo) / np.maximum(hi - lo, np.float32(1e-30)) * np.float32(1023)).astype(
        np.int64), 0, 1023)


def sort_keys(rays, key):
    if len(rays) == 0:
        return np.zeros(0, np.int64)
    org, d = rays[:, 0:3], rays[:, 4:7]
    origin = morton(quantize(org, org.min(0), org.max(0)))
    if key == "origin":
        return origin
    octant = (d[:, 0] < 0) | ((d[:, 1] < 0) << 1) | ((d[:, 2] < 0) << 2)
    if key == "octant-origin":
        return (octant.astype(np.int64) << 30) | origin
    unit = d / np.maximum(np.linalg.norm(d, axis=1), np.float32(1e-30))[:, None]
    direction = morton(quantize(unit, np.float32(-1), np.float32(1)))
    if key == "direction":
        return direction
    return ((direction >> 15) << 30) | origin  # dir-origin


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--block", type=int, default=0, help="rays per sorted block (0: all)")
    ap.add_argument("--key", default="octant-origin",
                    choices=("octant-origin", "origin", "direction", "dir-origin"))
    a = ap.parse_args()
    try:
        n, raw = rays_file.read(a.input)
    except (rays_file.RaysFileError, OSError) as e:
        sys.exit(f"sort-rays: {e}")
    rays = np.frombuffer(raw, "<f4", offset=rays_file.HEADER_BYTES).reshape(n, 8)
    keys = sort_keys(rays, a.key)
    block = a.block if a.block > 0 else max(n, 1)
    order = np.concatenate([b + np.argsort(keys[b:b + block], kind="stable")
                            for b in range(0, n, block)]) if n else np.zeros(0, np.int64)
    with open(a.output, "wb") as f:
        f.write(raw[:rays_file.HEADER_BYTES])
        f.write(rays[order].astype("<f4").tobytes())
    print("sort-rays: %d rays by %s in blocks of %d -> %s" % (n, a.key, block, a.output))


if __name__ == "__main__":
    main()
