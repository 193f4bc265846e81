"""Same answer? Each log of the independent generator's matrix diagnosed under conditions that must not change the
answer (alone; beside as many CPU-bound processes as there are cores; in this process without workers) and one
that may (NumPy's and OpenBLAS's AVX-512 paths switched off: another CPU's floating point), compared bit for bit
(``Diagnosis.fingerprint``: the answer without its wall times and file paths) against the run alone, with the first
place two answers differ.

Why: issue 16's "the same answer on a fast and on a slow machine". No decision reads a clock (budgets count
simulations), and the tests hold that two workers and none give the same answer on short logs; this measures it on
the matrix's 10 s logs under load, and shows how far another CPU's rounding carries.

    python3 bench/determinism.py [--only 5301,5405] [--duration 10] [--rate 5000] [--out bench/results/determinism.json]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from ident.fitting.ahead import CORES  # noqa: E402
from tests.diagnosis_matrix import load, matrix  # noqa: E402


def avx512_off() -> dict[str, str] | None:
    """The environment that keeps NumPy's and OpenBLAS's AVX-512 paths off (None: this CPU has none to switch off).
    NumPy reads ``NPY_DISABLE_CPU_FEATURES`` and OpenBLAS ``OPENBLAS_CORETYPE`` when they load, so only a new
    process takes them."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:   # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    wide = [f for f in __cpu_dispatch__ if (f.startswith("AVX512") or f == "X86_V4") and __cpu_features__.get(f)]
    if not wide:
        return None
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(wide), "OPENBLAS_CORETYPE": "Haswell"}


def child(stem: str, duration: float, rate: float, workers: int | None, out: str) -> None:
    """Diagnose ``stem``'s log in this process; its answer, fingerprint and wall time into ``out``."""
    from ident.diagnosis.engine import diagnose
    from ident.diagnosis.result import json_default

    case = next(c for c in matrix() if c.stem == stem)
    log, _ = load(case, duration, rate)
    t0 = time.perf_counter()
    d = diagnose(log, resolution_pulses=0, export_fmu=False, workers=workers)
    Path(out).write_text(json.dumps({"fingerprint": d.fingerprint(), "wall_s": time.perf_counter() - t0,
                                     "named": [e.name for e in d.effects],
                                     "tentative": [e.tentative for e in d.effects],
                                     "magnitudes": [e.magnitude for e in d.effects],
                                     "final_nrmse_load": d.steps[-1].nrmse_load, "answer": d.answer()},
                                    default=json_default))


def first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """Where ``a`` and ``b`` first differ (a path into the answer, with both values), or None."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in list(a) + [k for k in b if k not in a]:
            d = first_difference(a.get(k), b.get(k), f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    if a == b or (a != a and b != b):
        return None
    if isinstance(a, str) and isinstance(b, str):   # a sentence: where it starts to differ
        i = next((i for i, (x, y) in enumerate(zip(a, b)) if x != y), min(len(a), len(b)))
        a, b = a[max(0, i - 30):i + 50], b[max(0, i - 30):i + 50]
    return f"{path}: {str(a)[:160]} | {str(b)[:160]}"


def run(stem: str, name: str, args: argparse.Namespace, env: dict[str, str], workers: int | None,
        busy: int, folder: Path) -> dict[str, Any]:
    out = folder / f"{stem}-{name}.json"
    cmd = [sys.executable, __file__, "--child", stem, "--duration", str(args.duration), "--rate", str(args.rate),
           "--child-out", str(out)] + ([] if workers is None else ["--workers", str(workers)])
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(busy)]
    try:
        subprocess.run(cmd, env={**os.environ, **env}, check=True)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    return json.loads(out.read_text())


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", default="5301", help="comma-separated seeds or log names of the matrix")
    ap.add_argument("--duration", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=5000.0)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "determinism.json"))
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--child-out", help=argparse.SUPPRESS)
    ap.add_argument("--workers", type=int, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args.child, args.duration, args.rate, args.workers, args.child_out)
        return 0
    keep = {x for x in args.only.split(",") if x}
    stems = [c.stem for c in matrix() if str(c.seed) in keep or c.stem in keep]
    wide = avx512_off()
    conditions = [("alone", {}, None, 0), (f"beside {CORES} CPU-bound processes", {}, None, CORES),
                  ("no workers (this process)", {}, 0, 0)]
    conditions += [("AVX-512 paths off (NumPy, OpenBLAS)", wide, None, 0)] if wide else []
    folder = Path(tempfile.mkdtemp(prefix="hdrive-determinism-"))
    report: dict[str, Any] = {"cores": CORES, "duration_s": args.duration, "sample_rate_hz": args.rate,
                              "avx512_off": wide or "not run: this CPU has no AVX-512 paths to switch off",
                              "logs": {}}
    for stem in stems:
        rows = []
        for name, env, workers, busy in conditions:
            r = run(stem, name, args, env, workers, busy, folder)
            same = r["fingerprint"] == rows[0]["fingerprint"] if rows else True
            diff = None if same else first_difference(rows[0]["answer"], r["answer"])
            rows.append({**r, "condition": name, "same_as_alone": same, "first_difference": diff})
            print(f"{stem} | {name}: {r['wall_s']:.0f} s, named {r['named']} (tentative {r['tentative']}), "
                  + ("the same answer to the last bit" if same else f"differs: {diff}"), flush=True)
        report["logs"][stem] = [{k: v for k, v in row.items() if k != "answer"} for row in rows]
    Path(args.out).write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
