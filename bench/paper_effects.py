"""Benchmark of the paper-effects study (ident.studies.paper_effects; target: the whole write_paper_effects run with its
defaults in at most ~10 minutes on 2 cores).

- one impulse resolution (threshold search + N = 300 experiment) per effect case, serially in one process, at
  f_l* = 0.1 (nominal) and f_l* = 0.01 (the slowest level: the ringing decays slowly, the RK4 propagator runs long);
- the whole write_paper_effects run with its defaults (13 levels, N = 300, all cases + the best combination) on
  Dask with local worker processes.

Prints the figures and writes bench/results/paper_effects.json. ``python bench/paper_effects.py [--quick]``
(``--quick``: only the per-case timings).
"""
from __future__ import annotations

import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

from ident import DriveParams, impulse_resolution
from ident.studies.paper_effects import EFFECT_CASES, write_paper_effects


def main(quick: bool = False) -> dict:
    base = DriveParams()
    per_case = {}
    for case in EFFECT_CASES:
        row = {}
        for f in (0.1, 0.01):
            t0 = time.perf_counter()
            r = impulse_resolution(case.params(base, f), n_pulses=300)
            row[f"f_l_star_{f:g}_s"] = time.perf_counter() - t0
            row[f"f_l_star_{f:g}_median_tests"] = len(r.median_tests)
        per_case[case.name] = row
        print(f"{case.name:26s} one impulse resolution, N = 300: {row['f_l_star_0.1_s']:6.2f} s at f_l* = 0.1, "
              f"{row['f_l_star_0.01_s']:6.2f} s at f_l* = 0.01", flush=True)
    results: dict = {
        "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "cpu": platform.machine()},
        "impulse_resolution_n300_s": per_case,
        "targets": {"write_paper_effects_s": 600.0},
    }
    if not quick:
        with tempfile.TemporaryDirectory() as tmp:
            t0 = time.perf_counter()
            sweep, report = write_paper_effects(Path(tmp) / "paper_effects")
            total = time.perf_counter() - t0
            summary = sweep.summary()
        df = sweep.to_frame()
        results.update({
            "write_paper_effects_s": total, "levels": len(sweep.f_l_star), "n_pulses": int(df["n_pulses"].iloc[0]),
            "cases": len(sweep.cases), "tasks": len(df), "task_cpu_s_total": float(df["elapsed_s"].sum()),
            "task_cpu_s_by_case": df.groupby("case", sort=False)["elapsed_s"].sum().to_dict(),
            "summary": summary.to_dict(orient="records"),
        })
        print(f"write_paper_effects (defaults: {len(sweep.f_l_star)} levels, N = {results['n_pulses']}, "
              f"{len(sweep.cases)} cases incl. the combination): {total:.0f} s wall on Dask ({os.cpu_count()} local "
              f"workers; target 600 s), {results['task_cpu_s_total']:.0f} s of task time")
        cols = ["case", "slope_um", "r2", "growth", "first_over_median_hi", "linear", "avalanche"]
        print(summary[cols].to_string(index=False, float_format=lambda v: f"{v:.3g}"))
    out = Path(__file__).resolve().parent / "results" / "paper_effects.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2, default=float))
    print(f"written {out}")
    return results


if __name__ == "__main__":
    main(quick="--quick" in sys.argv[1:])
