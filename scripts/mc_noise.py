#!/usr/bin/env python3
"""mc_noise.py — per-bin relative noise of Monte Carlo J tables, from two independent runs.

    scripts/mc_noise.py DIR_SEED1 DIR_SEED2        (two grids made with different --seed)
    scripts/mc_noise.py PREFIX_A PREFIX_B          (two single tables)

For each pair of tables A, B of the same material and order, the relative standard error
of one table in bin i is estimated as |A_i - B_i| / (sqrt(2) * (A_i + B_i) / 2). Reported:
the energy-weighted median of that noise over bins (what most of the light sees), the
energy-weighted 90th percentile, and the share of the energy in bins whose noise is below
5% and 10%. Works without numpy (the standard library reads the .npy directly).
"""
import array
import json
import math
import os
import sys


def load(prefix):
    with open(prefix + ".json") as f:
        meta = json.load(f)
    with open(prefix + ".npy", "rb") as f:
        raw = f.read()
    assert raw[:6] == b"\x93NUMPY" and raw[6] == 1, prefix + ".npy: not npy v1"
    header_len = raw[8] | (raw[9] << 8)
    data = array.array("f")
    data.frombytes(raw[10 + header_len:])
    if sys.byteorder != "little":
        data.byteswap()
    return meta, data


def bin_measures(meta):
    """Ring volume times solid angle of every bin, in file order (z, rho, theta, phi)."""
    ax = meta["axes"]
    z, rho, th, ph = ax["z"], ax["rho"], ax["theta"], ax["phi"]
    vol = [math.pi * (rho[j + 1] ** 2 - rho[j] ** 2) * (z[i + 1] - z[i])
           for i in range(len(z) - 1) for j in range(len(rho) - 1)]
    omega = [(math.cos(th[k]) - math.cos(th[k + 1])) * (ph[l + 1] - ph[l]) * 2.0
             for k in range(len(th) - 1) for l in range(len(ph) - 1)]
    return vol, omega


def weighted_quantile(pairs, q):
    pairs.sort()
    total = sum(w for _, w in pairs)
    acc = 0.0
    for value, w in pairs:
        acc += w
        if acc >= q * total:
            return value
    return float("nan")


def compare(prefix_a, prefix_b):
    meta, a = load(prefix_a)
    meta_b, b = load(prefix_b)
    assert meta["axes"] == meta_b["axes"], "different bins"
    vol, omega = bin_measures(meta)
    nd = len(omega)
    pairs = []
    energy = 0.0
    for s, v in enumerate(vol):
        base = s * nd
        for d in range(nd):
            x, y = a[base + d], b[base + d]
            mean = 0.5 * (x + y)
            if mean <= 0.0:
                continue
            e = mean * v * omega[d]
            energy += e
            pairs.append((abs(x - y) / (math.sqrt(2.0) * mean), e))
    below5 = sum(w for r, w in pairs if r < 0.05) / energy
    below10 = sum(w for r, w in pairs if r < 0.10) / energy
    median = weighted_quantile(pairs, 0.5)
    p90 = weighted_quantile(pairs, 0.9)
    captured = meta["energy_captured"] / meta["energy_expected"] if meta["energy_expected"] else 1.0
    print(f"{os.path.basename(prefix_a):28s} photons {meta['photons']:>10d}  captured "
          f"{100 * captured:6.2f}%  noise: median {100 * median:5.2f}%  p90 {100 * p90:6.2f}%  "
          f"energy in bins <5%: {100 * below5:5.1f}%  <10%: {100 * below10:5.1f}%")


def main():
    if len(sys.argv) != 3:
        print(__doc__)
        return 2
    first, second = sys.argv[1], sys.argv[2]
    if os.path.isdir(first):
        names = sorted(n[:-5] for n in os.listdir(first) if n.endswith(".json"))
        for name in names:
            if os.path.exists(os.path.join(second, name + ".json")):
                compare(os.path.join(first, name), os.path.join(second, name))
    else:
        compare(first, second)
    return 0


if __name__ == "__main__":
    sys.exit(main())
