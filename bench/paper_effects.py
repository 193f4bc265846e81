"""Benchmark of the paper-effects study (ident.studies.paper_effects; target: the whole write_paper_effects run with its
defaults in at most ~10 minutes on 2 cores).

- one impulse resolution (threshold search + N = 300 experiment) per effect case, serially in one process, at
  f_l* = 0.1 (nominal) and f_l* = 0.01 (the slowest level: the ringing decays slowly, the RK4 propagator runs long);
- the whole write_paper_effects run with its defaults (13 levels, N = 300, all cases + the best combination) on
  Dask with local worker processes.

Prints the figures and writes bench/results/paper_effects.json. ``python bench/paper_effects.py [--quick]``
(``--quick``: only the per-case timings).

``python bench/paper_effects.py --search [--budget N] [--confirm K] [--seed S]``: the search of
``hdrive paper-effects --search`` (ident.studies.paper_search; target: the defaults in at most 10 minutes on 2 cores)
on Dask with local worker processes: wall time per stage, task time, the machine's load average before and after
(other work on the machine), the Pareto set and what each claim needs; writes bench/results/paper_search.json and
the report beside it (bench/results/paper_search/).
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


def search_main(budget: int, confirm: int, seed: int) -> dict:
    import shutil

    from ident.studies.paper_search_report import reach, write_paper_search

    out_dir = Path(__file__).resolve().parent / "results" / "paper_search"
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    search, report = write_paper_search(out_dir.with_name("paper_search.tmp"), budget=budget, confirm=confirm,
                                        seed=seed, progress=True)
    total = time.perf_counter() - t0
    shutil.rmtree(out_dir, ignore_errors=True)
    report.parent.rename(out_dir)
    df = search.to_frame()
    results = {
        "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "cpu": platform.machine()},
        "load_average_before": load_before, "load_average_after": os.getloadavg(),
        "search_s": total, "target_s": 600.0, "budget": budget, "confirm": confirm, "seed": seed,
        "stage_s": search.stage_s, "evaluations_by_stage": df["stage"].value_counts().to_dict(),
        "task_s_by_stage": df.groupby("stage")["task_s"].sum().to_dict(), "task_s_total": float(df["task_s"].sum()),
        "failed": int((df["error"] != "").sum()), **search.to_dict(), "reach": reach(search),
    }
    print(f"search (budget {budget}, confirm {confirm}, seed {seed}): {total:.0f} s wall on Dask ({os.cpu_count()} "
          f"local workers; target 600 s), {results['task_s_total']:.0f} s of task time; load average before "
          f"{load_before[0]:.1f}, after {results['load_average_after'][0]:.1f}")
    for stage, sec in search.stage_s.items():
        print(f"  {stage:14s} {results['evaluations_by_stage'].get(stage, 0):4d} evaluations  {sec:6.0f} s wall  "
              f"{results['task_s_by_stage'].get(stage, 0.0):7.0f} s task")
    for i, e in enumerate(search.pareto(), 1):
        print(f"  {i}. {e.candidate.label}: " + ", ".join(f"{k} {v.value:.3g}{'*' if v.met else ''}"
                                                          for k, v in e.claims.items()))
    out = Path(__file__).resolve().parent / "results" / "paper_search.json"
    out.write_text(json.dumps(results, indent=2, default=float))
    print(f"written {out} and {out_dir}")
    return results


def _option(name: str, default: int) -> int:
    args = sys.argv[1:]
    return int(args[args.index(name) + 1]) if name in args else default


if __name__ == "__main__":
    if "--search" in sys.argv[1:]:
        from ident.studies.paper_search import DEFAULT_BUDGET, DEFAULT_CONFIRM

        search_main(_option("--budget", DEFAULT_BUDGET), _option("--confirm", DEFAULT_CONFIRM), _option("--seed", 0))
    else:
        main(quick="--quick" in sys.argv[1:])
