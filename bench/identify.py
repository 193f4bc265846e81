"""Benchmark and accuracy study of the identifier (issue 4), on synthetic logs from the FMU and on EMPS.

- nominal drive + 20 random drives (K* in [1e5, 1e7], J_l* in [500, 1e4], f_l* in [0.01, 1], log-uniform),
  10 s logs at 5 kHz with the documented default excitation, encoder quantization, 2 nm load noise: error of
  every parameter, whether its 95 % interval covers the truth, wall time (target <= 60 s per log);
- the estimator's spread over noise realizations on the nominal drive against the Cramer-Rao bound;
- the EMPS rigid fit (target <= 10 s).

Prints a summary and writes bench/results/identify.json. Usage: python bench/identify.py [n_random] [n_noise]
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

from ident import DriveParams
from ident.fitting.identify import NAMES, identify
from ident.fitting.synthetic import synthetic_log


def one(p: DriveParams, seed: int) -> dict:
    log = synthetic_log(p, duration_s=10.0, rate_hz=5000.0, load_offset_rad=1e-5 * (seed % 7 - 3), seed=seed)
    t0 = time.perf_counter()
    fit = identify(log)
    wall = time.perf_counter() - t0
    row = {"seed": seed, "wall_s": wall, "warnings": fit.warnings, "residual_over_noise": fit.fit["residual_over_noise"]}
    for k in NAMES:
        e, truth = fit.estimates[k], getattr(p, k)
        row[k] = {"truth": truth, "value": e.value, "rel_error": e.value / truth - 1, "rel_std": e.std / e.value,
                  "covered": bool(e.ci95[0] <= truth <= e.ci95[1]),
                  "cramer_rao_rel": float(math.sqrt(fit.cov_noise_only[NAMES.index(k), NAMES.index(k)]))}
    return row


def main(n_random: int = 20, n_noise: int = 10) -> dict:
    rng = np.random.default_rng(2026)
    drives = [DriveParams()] + [DriveParams.from_nondim(10 ** rng.uniform(5, 7), 10 ** rng.uniform(math.log10(500), 4),
                                                        10 ** rng.uniform(-2, 0)) for _ in range(n_random)]
    rows = []
    for i, p in enumerate(drives):
        row = one(p, seed=i)
        rows.append(row)
        print(f"drive {i:2d} K*={p.K_star:.3g} J_l*={p.J_l_star:.4g} f_l*={p.f_l_star:.3g}: "
              + " ".join(f"{k} {row[k]['rel_error']:+.1e}{'' if row[k]['covered'] else ' (not covered)'}"
                         for k in NAMES) + f"  {row['wall_s']:.1f} s", flush=True)
    random_rows = rows[1:]
    covered = {k: sum(r[k]["covered"] for r in random_rows) for k in NAMES}
    noise = [one(DriveParams(), seed=1000 + s) for s in range(n_noise)]
    spread = {k: {"std_rel": float(np.std([r[k]["rel_error"] for r in noise], ddof=1)),
                  "cramer_rao_rel": float(np.mean([r[k]["cramer_rao_rel"] for r in noise]))} for k in NAMES}
    emps = None
    try:
        from ident.studies.emps import find_emps_data, identify_rigid, load_emps

        data = find_emps_data()
        if data is not None:
            log = load_emps(data / "DATA_EMPS.mat")
            t0 = time.perf_counter()
            identify_rigid(log)
            emps = {"fit_s": time.perf_counter() - t0}
    except ImportError:
        pass
    result = {"machine": {"cores": os.cpu_count()}, "drives": rows, "covered_of_20": covered,
              "max_abs_rel_error": {k: max(abs(r[k]["rel_error"]) for r in rows) for k in NAMES},
              "max_wall_s": max(r["wall_s"] for r in rows), "mean_wall_s": float(np.mean([r["wall_s"] for r in rows])),
              "noise_monte_carlo": spread, "emps": emps}
    out = Path(__file__).resolve().parent / "results" / "identify.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"max |relative error|: {result['max_abs_rel_error']}")
    print(f"95 % intervals covering the truth (of {len(random_rows)} random drives): {covered}")
    print(f"wall time per 10 s log: mean {result['mean_wall_s']:.1f} s, max {result['max_wall_s']:.1f} s (target 60)")
    for k, v in spread.items():
        print(f"{k}: spread over {n_noise} noise seeds {v['std_rel']:.2e} vs Cramer-Rao {v['cramer_rao_rel']:.2e}")
    print(f"EMPS fit: {emps}")
    print(f"written {out}")
    return result


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
