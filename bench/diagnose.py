"""Benchmark + acceptance matrix of the discrepancy workflow (issue 5 items 6 and 10).

For each effect of the library, a "measured" log is simulated by the FMU with that effect hidden at a realistic
magnitude (encoder quantization, 2 nm load noise, a seeded random excitation unlike the identifier's default),
and ``ident.diagnosis.engine`` runs from the base model. Also: a clean log (must name nothing), two effects together,
flexibility from the rigid model, and an effect outside the library (``OUT_OF_LIBRARY_CASES``: must name nothing
and say where the residual sits). Prints and saves bench/results/diagnose.json.

    python3 bench/diagnose.py [--duration 6] [--cases viscous_load,hardening] [--workers 2]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.diagnosis.engine import diagnose  # noqa: E402
from ident.fitting.synthetic import HIDDEN_EFFECT_CASES, OUT_OF_LIBRARY_CASES, hidden_effect_log, out_of_library_log  # noqa: E402
from ident.model.effects import EFFECTS  # noqa: E402
from ident.model.params import DriveParams  # noqa: E402

CASES = HIDDEN_EFFECT_CASES


def run_case(name: str, duration: float, workers: int) -> dict:
    outside = name in OUT_OF_LIBRARY_CASES
    hidden, _, expected = ({}, None, []) if outside else CASES[name]
    log = out_of_library_log(name, duration) if outside else hidden_effect_log(name, duration)
    t0 = time.perf_counter()
    d = diagnose(log, model="rigid" if name == "flexibility" else "two-inertia", resolution_pulses=0,
                 workers=workers)
    elapsed = time.perf_counter() - t0
    named = [e.name for e in d.effects]
    magnitudes = []
    for e in d.effects:
        truth = DriveParams().K_s if e.name == "flexibility" else hidden.get(EFFECTS[e.name].magnitude_param)
        truth = None if truth is None else abs(truth)
        magnitudes.append({"effect": e.name, "magnitude": e.magnitude, "ci95": list(e.ci95), "truth": truth,
                           "rel_err": abs(e.magnitude - truth) / truth if truth else None, "margin": e.margin})
    over_noise = d.steps[-1].extra.get("residual_over_noise_load")
    ok = sorted(named) == sorted(expected) and all(m["rel_err"] is not None and m["rel_err"] <= 0.1
                                                   for m in magnitudes)
    if outside:
        ok = not named and bool(d.unexplained)
    elif expected:
        ok = ok and d.steps[0].nrmse_load / d.steps[-1].nrmse_load >= 5
    out = {"case": name, "expected": expected, "named": named, "elapsed_s": elapsed,
           "nrmse_load_steps": [s.nrmse_load for s in d.steps],
           "removed": [n for s in d.steps for n in s.extra.get("removed", [])],
           "shrink": d.steps[0].nrmse_load / d.steps[-1].nrmse_load, "final_residual_over_noise": over_noise,
           "magnitudes": magnitudes, "unexplained": d.unexplained, "notes": d.notes, "ok": ok,
           "candidates": [[{k: (None if isinstance(v, float) and v != v else v) for k, v in row.items()
                            if k in ("candidate", "start", "heldback_gain", "elapsed_s", "error")}
                           for row in s.candidates.to_dict("records")] for s in d.steps if len(s.candidates)]}
    print(json.dumps(out), flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--cases", default=",".join([*CASES, *OUT_OF_LIBRARY_CASES]))
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "diagnose.json"))
    args = ap.parse_args()
    results = [run_case(c, args.duration, args.workers) for c in args.cases.split(",")]
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"cores": os.cpu_count(), "duration_s": args.duration,
                                          "sample_rate_hz": 5000.0, "results": results}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
