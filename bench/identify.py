"""Benchmark of the identifier on logs it did not make (issue 21): accuracy against the Cramer-Rao bound, interval
coverage, the noise estimate, identifiability verdicts, speed and memory.

Logs come from the independent reference generator (``tests/reference/generator``: no code shared with the FMU or
``ident``), read through the product's reader (CSV + sidecar).

- **suite** (``IDENTIFICATION_SLOW_SUITE``: 60 seeded cases, drives K* 1e5-1e7, J_l* 500-1e4, f_l* 0.01-1, the six
  excitations, sample rates 1-10 kHz, load noise 1-20 nm, quantized encoders, offsets, wound starts; 4 s logs):
  per log and parameter the error, the Cramer-Rao bound at the truth (true noise), whether the 95 % interval covers
  the truth, the identifiability verdict, sigma_load_rad over the true noise, the residual over the noise, warnings;
  the 95 % coverage over the identifiable pairs (target 90-99 %), the estimates within 3 bound-sigmas wherever the
  bound is <= 1 %, the noise ratios (target within 20 %);
- **speed** (the same seeds as 10 s logs at 5 kHz, one process; ``--helper`` on / off / auto: whether the fit runs
  its independent simulations half on the second core, ``ident.fitting.ahead``): wall time per identification (target
  median <= 10 s, max <= 30 s), and beside it each fit's residual over the noise, its mismatch warning and its
  errors against the truth;
- **memory**: peak resident memory of ``hdrive identify`` (a fresh process) on 10, 30 and 60 s logs at 5 kHz (target
  linear, <= 1 GB at 60 s).

Prints a summary and writes bench/results/identify.json. Usage:
``python bench/identify.py [--cases N] [--speed N] [--memory] [--helper auto|on|off] [--out PATH]``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ident.fitting import ahead
from ident.fitting.identify import NAMES, IdentificationError, identify
from ident.fitting.logs import LogError
from tests.ident_support import cramer_rao_at_truth, read_back
from tests.reference.generator import IDENTIFICATION_SLOW_SUITE, identification_case


def one(seed: int, kind: str, folder: Path, duration_s: float | None = None, rate_hz: float | None = None,
        crb: bool = True) -> dict:
    """Identify one generated log; the row of the results table."""
    kw = {} if duration_s is None else {"duration_s": duration_s, "rate_hz": rate_hz}
    g = identification_case(seed, kind, **kw)
    log = read_back(g, folder, f"{seed}_{kind}")
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        fit = identify(log)
    except (IdentificationError, LogError) as exc:
        return {"seed": seed, "kind": kind, "error": str(exc), "wall_s": time.perf_counter() - t0,
                "cpu_s": time.process_time() - c0}
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    tr = g.truth
    bound = cramer_rao_at_truth(log, g) if crb else np.full(3, math.nan)
    row = {"seed": seed, "kind": kind, "rate_hz": tr.sample_rate_hz, "noise_m": tr.noise_m, "samples": log.n,
           "wall_s": wall, "cpu_s": cpu, "identifiable": fit.identifiable, "warnings": fit.warnings,
           "sigma_ratio": fit.sigma_load_rad / tr.noise_sigma_rad,
           "residual_over_noise": fit.fit["residual_over_noise"], "stages": len(fit.stages)}
    for i, k in enumerate(NAMES):
        e, truth = fit.estimates[k], getattr(tr, k)
        err_ln = math.log(e.value / truth)
        row[k] = {"truth": truth, "value": e.value, "rel_error": e.value / truth - 1, "rel_std": e.std / e.value,
                  "covered": bool(e.ci95[0] <= truth <= e.ci95[1]), "identifiable": e.identifiable,
                  "reason": e.reason, "crb_rel_at_truth": float(bound[i]),
                  "error_over_crb": err_ln / float(bound[i]) if bound[i] > 0 else math.nan}
    return row


def mismatched(rows: list[dict]) -> list[tuple[int, str]]:
    """(seed, kind) of the fits that carry the identifier's model-mismatch warning ("does not explain")."""
    return [(r["seed"], r["kind"]) for r in rows if any("does not explain" in w for w in r["warnings"])]


def summarize(rows: list[dict]) -> dict:
    ok = [r for r in rows if "error" not in r]
    coverage = {}
    for k in NAMES:
        pairs = [r[k] for r in ok if r[k]["identifiable"]]
        coverage[k] = {"identifiable": len(pairs), "covered": sum(p["covered"] for p in pairs)}
    total = sum(c["identifiable"] for c in coverage.values())
    covered = sum(c["covered"] for c in coverage.values())
    tight = [(r["seed"], k, r[k]["error_over_crb"]) for r in ok for k in NAMES if r[k]["crb_rel_at_truth"] <= 0.01]
    return {"logs": len(rows), "errors": [r for r in rows if "error" in r], "coverage": coverage,
            "coverage_all": covered / total if total else math.nan,
            "within_3_crb_where_crb_le_1pct": {"pairs": len(tight), "within": sum(abs(z) <= 3 for _, _, z in tight),
                                               "outside": [t for t in tight if not abs(t[2]) <= 3]},
            "sigma_ratio": {"min": min(r["sigma_ratio"] for r in ok), "max": max(r["sigma_ratio"] for r in ok)},
            "not_identifiable": [(r["seed"], r["kind"]) for r in ok if not r["identifiable"]],
            "mismatch_warnings": mismatched(ok)}


def speed(cases: list[tuple[int, str]], folder: Path) -> dict:
    """Wall time of 10 s logs at 5 kHz (the same drives and excitations), and how right each fit is: a fast wrong
    answer is no speed figure (the residual over the noise, the identifier's own "does not explain" warning, the
    errors against the generator's truth, each estimate's verdict and whether its interval holds the truth)."""
    rows = []
    for seed, kind in cases:
        row = one(seed, kind, folder, 10.0, 5000.0, crb=False)
        rows.append(row)
        print(f"  speed {seed} {kind:13s} {row['wall_s']:6.1f} s wall, {row['cpu_s']:6.1f} s cpu, "
              f"{row.get('residual_over_noise', math.nan):8.3g}x the noise", flush=True)
    walls, cpus = [r["wall_s"] for r in rows], [r["cpu_s"] for r in rows]
    ok = [r for r in rows if "error" not in r]
    return {"logs": len(walls), "median_s": float(np.median(walls)), "max_s": float(np.max(walls)),
            "median_cpu_s": float(np.median(cpus)), "max_cpu_s": float(np.max(cpus)), "walls_s": walls,
            "cpus_s": cpus, "errors": [(r["seed"], r["kind"], r["error"]) for r in rows if "error" in r],
            "residual_over_noise": {f"{r['seed']}_{r['kind']}": r["residual_over_noise"] for r in ok},
            "mismatch_warnings": mismatched(ok),
            "max_abs_rel_error": {k: max((abs(r[k]["rel_error"]) for r in ok), default=math.nan) for k in NAMES},
            "rel_errors": {f"{r['seed']}_{r['kind']}": {k: r[k]["rel_error"] for k in NAMES} for r in ok},
            "verdicts": {f"{r['seed']}_{r['kind']}": {k: {"identifiable": r[k]["identifiable"],
                                                          "covered": r[k]["covered"]} for k in NAMES} for r in ok}}


def memory(folder: Path) -> dict:
    """Peak RSS [MB] of `hdrive identify` in a fresh process on 10, 30 and 60 s logs at 5 kHz (default excitation
    of the first suite drive)."""
    seed, _ = IDENTIFICATION_SLOW_SUITE[0]
    out = {}
    for seconds in (10.0, 30.0, 60.0):
        g = identification_case(seed, "default", duration_s=seconds, rate_hz=5000.0)
        csv, _ = g.write(folder, f"mem_{int(seconds)}")
        code = ("import resource, sys; from ident.cli import main; rc = main(['identify', sys.argv[1], '--json']); "
                "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)")
        proc = subprocess.run([sys.executable, "-c", code, str(csv)], capture_output=True, text=True,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        rss_mb = int(proc.stderr.strip().splitlines()[-1]) / 1024
        out[f"{int(seconds)}s"] = {"peak_rss_mb": rss_mb, "exit": proc.returncode}
        print(f"  memory {seconds:4.0f} s log: {rss_mb:7.1f} MB (exit {proc.returncode})", flush=True)
    return out


def machine() -> dict:
    load = os.getloadavg()
    return {"cores": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version(),
            "processor": platform.processor() or platform.machine(), "load_average_at_start": load}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=60, help="suite cases (default 60)")
    ap.add_argument("--speed", type=int, default=60, help="10 s / 5 kHz logs timed (default 60; 0 skips)")
    ap.add_argument("--memory", action="store_true", help="also measure peak memory on 10/30/60 s logs")
    ap.add_argument("--helper", choices=("auto", "on", "off"), default="auto",
                    help="simulations run ahead on the second core (ident.fitting.ahead.MODE; default auto)")
    ap.add_argument("--out", default=str(ROOT / "bench" / "results" / "identify.json"))
    args = ap.parse_args(argv)
    cases = IDENTIFICATION_SLOW_SUITE[: args.cases]
    ahead.MODE = args.helper
    result: dict = {"machine": machine(), "helper": args.helper}
    with tempfile.TemporaryDirectory(prefix="hdrive-bench-") as tmp:
        rows = []
        for seed, kind in cases:
            rows.append(one(seed, kind, Path(tmp)))
            r = rows[-1]
            print(f"{seed} {kind:13s} " + (r["error"] if "error" in r else
                  " ".join(f"{k[:1]} {r[k]['rel_error']:+.1e}/{r[k]['crb_rel_at_truth']:.0e}"
                           f"{'' if r[k]['covered'] else 'X'}{'' if r[k]['identifiable'] else 'N'}" for k in NAMES)
                  + f" sig {r['sigma_ratio']:.3f} ron {r['residual_over_noise']:.3f} {r['wall_s']:.1f} s "
                    f"(cpu {r['cpu_s']:.1f} s)"),
                  flush=True)
        if rows:
            result.update(suite=rows, summary=summarize(rows))
        if args.speed:  # the suite's first drives and excitations, whether or not the suite itself ran
            result["speed"] = speed(IDENTIFICATION_SLOW_SUITE[: args.speed], Path(tmp))
        if args.memory:
            result["memory"] = memory(Path(tmp))
    result["machine"]["load_average_at_end"] = os.getloadavg()
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2, default=float))
    if "summary" in result:
        print(json.dumps(result["summary"], indent=2, default=float))
    if "speed" in result:
        print(f"speed: median {result['speed']['median_s']:.1f} s, max {result['speed']['max_s']:.1f} s "
              f"(targets 10 / 30 s); the identifier's own 'does not explain' warning on "
              f"{len(result['speed']['mismatch_warnings'])} of {result['speed']['logs']}: "
              f"{result['speed']['mismatch_warnings']}")
    print(f"written {args.out}")
    return result


if __name__ == "__main__":
    main()
