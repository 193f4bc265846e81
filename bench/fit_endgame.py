"""How many of a diagnosis's simulations come after each of its fits was already within a few noise variances of
the best cost that fit reached: in hindsight, the share a perfect stop rule could save (a rule that stops sooner can
only be judged by the sizes and intervals it then gives). Every fit of the diagnosis's model problems (candidates'
refits, probes, polish, halves, shapes; the base identification is not one of them) is traced, in one process
(``workers=0``); the log is one of the matrix's (``tests/diagnosis_matrix.py``), 10 s at 5 kHz.

    python3 bench/fit_endgame.py LOG_STEM [--out bench/results/fit_endgame.json]
            (e.g. single-5102-stribeck-medium-steps-gaussian)
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.diagnosis.engine import diagnose  # noqa: E402
from ident.diagnosis.models import problem as P  # noqa: E402
from tests.diagnosis_matrix import load, matrix  # noqa: E402

TRACES: dict[int, list[float]] = {}   # fit number -> the cost [noise variances] of each of its new simulations
_NUMBERS = itertools.count()
_RESIDUALS = P.ModelProblem.residuals
TOLERANCES = (0.01, 0.1, 1.0)


def _traced(self, theta):
    """``ModelProblem.residuals``, recording each new simulation's cost under the problem's own number."""
    before = self.evaluations
    r = _RESIDUALS(self, theta)
    if self.evaluations > before:
        if not hasattr(self, "_endgame_number"):
            self._endgame_number = next(_NUMBERS)
        TRACES.setdefault(self._endgame_number, []).append(float(r @ r))
    return r


def late_share(traces: list[list[float]], tol: float) -> int:
    """Simulations after each fit first came within ``tol`` noise variances of its own best cost."""
    late = 0
    for costs in traces:
        best = min(costs)
        late += len(costs) - 1 - next(i for i, c in enumerate(costs) if c <= best + tol)
    return late


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("log", help="a log of the matrix by its stem, e.g. single-5102-stribeck-medium-steps-gaussian")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "fit_endgame.json"))
    args = ap.parse_args()
    case = next((c for c in matrix() if c.stem == args.log), None)
    if case is None:
        ap.error(f"no log {args.log!r} in the matrix (tests/diagnosis_matrix.py)")
    log, _ = load(case, 10.0, 5000.0)
    P.ModelProblem.residuals = _traced
    t0 = time.perf_counter()
    diag = diagnose(log, resolution_pulses=0, workers=0)
    traces = list(TRACES.values())
    total = sum(len(t) for t in traces)
    out = {"log": args.log, "fits": len(traces), "simulations": total, "named": [e.name for e in diag.effects],
           "elapsed_s": time.perf_counter() - t0,
           "late": {str(tol): late_share(traces, tol) for tol in TOLERANCES}}
    for tol in TOLERANCES:
        n = out["late"][str(tol)]
        print(f"within {tol} noise variances of each fit's best: {n} of {total} simulations after it "
              f"({100 * n / max(total, 1):.0f} %)")
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
