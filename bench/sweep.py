"""Benchmark of the resolution protocols through the FMU (issue 3 targets, 2 cores):

- the full 25-level friction sweep with N = 1000 pulses per experiment: at most 30 s wall;
- one nominal impulse resolution (threshold search + N = 1000 experiment): at most 3 s.

Prints the figures and writes bench/results/sweep.json.
"""
from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

from ident import DriveParams, impulse_resolution, linear_resolution
from ident.protocols.sweep import friction_sweep


def timed(fn):
    t0 = time.perf_counter()
    value = fn()
    return value, time.perf_counter() - t0


def main() -> dict:
    nominal = DriveParams()
    imp, t_imp = timed(lambda: impulse_resolution(nominal, n_pulses=1000))
    lin, t_lin = timed(lambda: linear_resolution(nominal, n_steps=1000))
    sweep, t_sweep = timed(lambda: friction_sweep(nominal, 25, 1000))  # Dask, local worker processes
    _, t_serial = timed(lambda: friction_sweep(nominal, 25, 1000, workers=0))
    pulses = sum(sum(n for _, _, n in r.median_tests) + r.n_pulses for r in sweep.results)
    results = {
        "machine": {"cores": os.cpu_count(), "python": platform.python_version(), "cpu": platform.machine()},
        "impulse_resolution_nominal_s": t_imp, "impulse_threshold": imp.threshold_amplitude,
        "impulse_resolution_um": imp.resolution_m * 1e6, "median_tests": len(imp.median_tests),
        "linear_resolution_nominal_s": t_lin, "linear_resolution_um": lin.resolution_m * 1e6,
        "sweep_25x1000_dask_s": t_sweep, "sweep_25x1000_serial_s": t_serial, "sweep_pulses_simulated": pulses,
        "targets": {"sweep_s": 30.0, "impulse_resolution_s": 3.0},
    }
    out = Path(__file__).resolve().parent / "results" / "sweep.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    print(f"nominal impulse resolution: {t_imp:.2f} s (target 3 s), {len(imp.median_tests)} median tests, "
          f"A_th = {imp.threshold_amplitude:.4f}, resolution {imp.resolution_m * 1e6:.4f} um")
    print(f"nominal linear resolution: {t_lin:.2f} s, {lin.counts} counts, {lin.resolution_m * 1e6:.3f} um")
    print(f"25-level sweep, N = 1000: {t_sweep:.1f} s on Dask ({os.cpu_count()} local workers), {t_serial:.1f} s "
          f"serial (target 30 s); {pulses:,} pulses simulated to rest")
    print(f"written {out}")
    return results


if __name__ == "__main__":
    main()
