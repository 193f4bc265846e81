"""The default test run's wall time with the machine loaded: the README's test command (``python3 -m pytest``,
with the xdist processes ``pyproject.toml`` sets: four since stop 69) with ``--load`` CPU-bound processes beside
it (each a busy Python loop), the way a developer's machine runs it beside a build or a benchmark. The target is
10 minutes on 2 cores, even loaded.

The independent references' results (the log generator's, the event-driven integrator's) are kept between runs
(``tests/reference/stored.py``); ``--cold`` runs with that store off, as a fresh machine runs it.

Prints the wall time, the pytest summary line and the load average, and writes them to ``--out`` (JSON).

    python3 bench/test_run.py --load 2 --out bench/results/test_run.json
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def loaded_run(load: int, cold: bool = False) -> dict:
    env = {**os.environ, "HDRIVE_REFERENCE_CACHE": "0"} if cold else None
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(load)]
    try:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider"], cwd=ROOT,
                              capture_output=True, text=True, env=env)
        wall = time.perf_counter() - t0
        load_avg = os.getloadavg()
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    lines = proc.stdout.strip().splitlines()
    return {"load_processes": load, "references": "made (store off)" if cold else "stored",
            "pytest_addopts": os.environ.get("PYTEST_ADDOPTS", ""),   # beside pyproject.toml's (e.g. "-n 3")
            "wall_s": round(wall, 1), "exit": proc.returncode,
            "summary": lines[-1] if lines else proc.stderr[-300:],
            "load_average_1_5_15": [round(x, 2) for x in load_avg],
            "failures_and_warnings": [ln for ln in lines if ln.startswith(("FAILED", "ERROR", "tests/"))][:40]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--load", type=int, nargs="+", default=[2], help="CPU-bound processes beside the run (default 2)")
    ap.add_argument("--cold", action="store_true", help="the references' results made, not read from their store")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "test_run.json")
    args = ap.parse_args()
    if any(n < 0 for n in args.load):
        ap.error(f"--load {args.load}: counts of processes must be >= 0")
    runs = []
    for n in args.load:
        r = loaded_run(n, args.cold)
        print(f"load {n}: {r['wall_s']:.0f} s wall, exit {r['exit']}: {r['summary']} "
              f"(load average {r['load_average_1_5_15'][0]})", flush=True)
        runs.append(r)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    out = {"machine": {"cores": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
           "commit": commit.stdout.strip(), "runs": runs}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
