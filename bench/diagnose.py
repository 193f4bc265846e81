"""Benchmark + acceptance matrix of the discrepancy loop (issue 16 items 2 and 4) on the independent generator's logs.

The matrix (``tests/diagnosis_matrix.py``): every library effect x 3 magnitude classes x 3 drives x 2 excitations
(126 logs, shape variants included), 20 clean logs, 10 two-effect logs, 10 logs with an effect outside the library;
here as 10 s logs at 5 kHz (the timing target: at most 2 minutes each on 2 cores). Each diagnosed log is appended to
``--out``.jsonl as it finishes (a long run can be resumed: logs already there are skipped); the summary per class
(named / missed / false, confident names, wall time median and max, what the screen ranked first) and the magnitude
errors where the generator's shape is the library's are printed and written to ``--out``.

    python3 bench/diagnose.py [--duration 10] [--rate 5000] [--classes single,clean] [--only hardening|5102|LOG]
                              [--quick]
                              [--workers N] [--out bench/results/diagnose.json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.diagnosis_matrix import CLASSES, matrix, run_case, summarize  # noqa: E402


def quick_sample(cases: list) -> list:
    """The first medium-magnitude case of each library effect, then the first 4 clean, 2 two-effect and 3
    outside-the-library cases, in the matrix's order (a sample for a machine that cannot run the 166 logs)."""
    single, seen = [], set()
    for c in cases:
        if c.cls == "single" and c.magnitude == "medium" and c.effect not in seen:
            seen.add(c.effect)
            single.append(c)
    limits = {"clean": 4, "two_effect": 2, "outside": 3}
    return single + [c for cls, n in limits.items() for c in [c for c in cases if c.cls == cls][:n]]


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=5000.0)
    ap.add_argument("--classes", default=",".join(CLASSES))
    ap.add_argument("--only", default="", help="comma-separated effects, seeds or log names (e.g. "
                    "single-5102-hardening-weak-steps-three_slope) to keep (default: all)")
    ap.add_argument("--quick", action="store_true",
                    help="a stratified sample of 16 logs instead of the matrix: the first medium-magnitude log of "
                         "each library effect, 4 clean, 2 two-effect and 3 outside-the-library logs")
    ap.add_argument("--workers", type=int, default=None, help="Dask workers per diagnosis (default: the cores)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "diagnose.json"))
    args = ap.parse_args()
    keep = {x for x in args.only.split(",") if x}
    cases = [c for c in matrix() if c.cls in args.classes.split(",")
             and (not keep or c.effect in keep or str(c.seed) in keep or c.stem in keep)]
    if args.quick:
        cases = quick_sample(cases)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    lines = out.with_suffix(".jsonl")
    done = {}
    if lines.is_file():
        for line in lines.read_text().splitlines():
            r = json.loads(line)
            done[r["case"]] = r
    t0 = time.perf_counter()
    for i, case in enumerate(cases):
        if case.stem in done:
            continue
        try:
            r = run_case(case, args.duration, args.rate, workers=args.workers)
        except Exception as exc:  # noqa: BLE001 - e.g. the generator cannot make this log: reported, not fatal
            print(f"[{i + 1}/{len(cases)}] {case.stem}: {type(exc).__name__}: {exc}", flush=True)
            continue
        r["load_avg_1min"] = os.getloadavg()[0]
        done[case.stem] = r
        with lines.open("a") as f:
            f.write(json.dumps(r, default=str) + "\n")
        print(f"[{i + 1}/{len(cases)} {time.perf_counter() - t0:7.0f} s] {case.stem}: named {r['named']} "
              f"(confident {r['confident']}), hidden {r['hidden']}, {r['elapsed_s']:.0f} s, load "
              f"{r['load_avg_1min']:.1f}", flush=True)
    results = [done[c.stem] for c in cases if c.stem in done]
    summary = summarize(results)
    out.write_text(json.dumps({"cores": os.cpu_count(), "duration_s": args.duration, "sample_rate_hz": args.rate,
                               "summary": summary, "results": results}, indent=2, default=str))
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
