"""How often the named sizes' 95 % intervals hold the truth over the sensor noise's redraws (issue 16, must-hold 2).

One true trajectory of the independent generator (``tests/reference/``: a single-effect case of the matrix, as
``bench/diagnose.py`` makes it), its load-angle noise drawn again for each draw (seeded, the generator's own noise
level and offset), each draw diagnosed by ``ident.diagnose`` as a user's log would be. Per draw: what was named,
how sure, each size with its interval against the generator's truth (where its shape is the library's). The summary:
the right effect's hit rate, the coverage of its intervals and the largest |z| (``diagnosis_matrix.coverage``, as
``bench/diagnose.py`` reports them), each draw's z.

    python3 bench/interval_coverage.py SEED:EFFECT:MAGNITUDE:EXCITATION [--draws 1,2,3,4,5] [--duration 10]
                                       [--rate 5000] [--workers N] [--out bench/results/interval_coverage.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.diagnosis_matrix import Case, coverage, generate, interval_z, score  # noqa: E402
from tests.ident_support import read_back  # noqa: E402


def redrawn(g0, draw: int):
    """``g0`` with its load-angle noise drawn again (seed 1000 + ``draw``), on the same true trajectory."""
    rng = np.random.default_rng(1000 + draw)
    noise = rng.normal(0.0, g0.truth.noise_sigma_rad, g0.true_load_pos_rad.size)
    return dataclasses.replace(g0, load_pos_rad=g0.true_load_pos_rad + g0.truth.offset_rad + noise)


def summary(case: Case, rows: list[dict]) -> dict:
    """Hit rate of the hidden effect, coverage of its intervals (where the truth is in the library's terms), max |z|."""
    sizes = [m for r in rows for m in r["magnitudes"] if m["effect"] == case.effect and m["truth"] is not None]
    held = coverage(sizes)
    return {"case": case.stem, "draws": len(rows), "named_right": sum(case.effect in r["named"] for r in rows),
            "confident_right": sum(case.effect in r["confident"] for r in rows), "intervals": held["n"],
            "hold": held["covered"], "max_abs_z": held["max_abs_z"], "z": [interval_z(m) for m in sizes],
            "errors_pct": [100 * (m["magnitude"] / m["truth"] - 1) for m in sizes],
            "elapsed_s": [r["elapsed_s"] for r in rows]}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("case", help="SEED:EFFECT:MAGNITUDE:EXCITATION, e.g. 5102:viscous_load:medium:steps")
    ap.add_argument("--draws", default="1,2,3,4,5")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=5000.0)
    ap.add_argument("--workers", type=int, default=None, help="Dask workers per diagnosis (default: the cores)")
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "interval_coverage.json"))
    args = ap.parse_args()
    seed, effect, magnitude, excitation = args.case.split(":")
    case = Case("single", int(seed), effect, magnitude, excitation)
    g0 = generate(case, args.duration, args.rate)
    from ident.diagnosis.engine import diagnose

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    rows = []
    for draw in (int(x) for x in args.draws.split(",")):
        g = redrawn(g0, draw)
        t0 = time.perf_counter()
        diag = diagnose(read_back(g), resolution_pulses=0, workers=args.workers)
        r = score(case, g.truth.to_dict(), diag, time.perf_counter() - t0)
        r["draw"] = draw
        rows.append(r)
        with out.with_suffix(".jsonl").open("a") as f:
            f.write(json.dumps(r, default=str) + "\n")
        print(f"draw {draw}: named {r['named']} (confident {r['confident']}), {r['elapsed_s']:.0f} s", file=sys.stderr)
    s = summary(case, rows)
    out.write_text(json.dumps(s, indent=2, default=str))
    print(json.dumps(s, indent=2, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
