"""Benchmark + acceptance matrix of the discrepancy workflow (issue 5 items 6 and 10).

For each effect of the library, a "measured" log is simulated by the FMU with that effect hidden at a realistic
magnitude (encoder quantization, 2 nm load noise, a seeded random excitation unlike the identifier's default),
and ``ident.diagnose`` runs from the base model. Also: a clean log (must name nothing), two effects together, and
flexibility from the rigid model. Prints and saves bench/results/diagnose.json.

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

from ident.diagnose import diagnose  # noqa: E402
from ident.params import DriveParams  # noqa: E402
from ident.synthetic import HIDDEN_EFFECT_CASES, hidden_effect_log  # noqa: E402

CASES = HIDDEN_EFFECT_CASES


def run_case(name: str, duration: float, workers: int) -> dict:
    hidden, mag_param, expected = CASES[name]
    log = hidden_effect_log(name, duration)
    t0 = time.perf_counter()
    d = diagnose(log, model="rigid" if name == "flexibility" else "two-inertia", resolution_pulses=0,
                 workers=workers)
    elapsed = time.perf_counter() - t0
    named = [e.name for e in d.effects]
    truth = hidden.get(mag_param, DriveParams().K_s if mag_param == "K_s" else None)
    mag = next((e.magnitude for e in d.effects if e.name in expected[:1]), None)
    out = {"case": name, "expected": expected, "named": named, "elapsed_s": elapsed,
           "nrmse_load_steps": [s.nrmse_load for s in d.steps],
           "shrink": d.steps[0].nrmse_load / d.steps[-1].nrmse_load,
           "magnitude": mag, "truth": truth,
           "magnitude_rel_err": (abs(abs(mag) - abs(truth)) / abs(truth)) if (mag is not None and truth) else None,
           "ci95": next((list(e.ci95) for e in d.effects if e.name in expected[:1]), None),
           "margins": [e.margin for e in d.effects], "unexplained": d.unexplained,
           "ok": sorted(named) == sorted(expected)}
    print(json.dumps(out), flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=6.0)
    ap.add_argument("--cases", default=",".join(CASES))
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
