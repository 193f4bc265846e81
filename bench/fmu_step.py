"""Benchmark of the FMU through fmpy: raw doStep rate, closed-loop control periods per second, pulse to rest.

Prints a table and writes bench/results/fmu_step.json. Target (issue 2): >= 100,000 closed-loop control periods
per second for FMI 2 on one core.
"""
from __future__ import annotations

import json
import math
import os
import platform
import time
from pathlib import Path

from ident import DriveParams, Plant


def best_rate(fn, n: int, repeats: int = 3) -> float:
    """Calls per second of fn(n) (which performs n calls), best of `repeats`."""
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(n)
        best = min(best, time.perf_counter() - t0)
    return n / best


def raw_do_step(plant: Plant, n: int) -> None:
    do_step = plant._do_step  # the FMU's doStep through ctypes, no Python work around it
    t = 0.0
    for _ in range(n):
        do_step(t, 1e-3)
        t += 1e-3


def closed_loop(plant: Plant, n: int) -> None:
    """PD on the quantized motor encoder at 1 kHz: set input, doStep, read outputs, compute the next torque."""
    p = plant.params
    kp, kd, sat = 200.0 * p.f_m, 19.2 * p.f_m * p.T_c, 20 * p.f_m
    plant.reset()
    target, prev, torque = 5, 0.0, 0.0
    for k in range(n):
        s = plant.step(torque, 1e-3)
        y = s.encoder_count * p.count_rad
        u = kp * (target * p.count_rad - y) - kd * (y - prev) / 1e-3
        prev = y
        torque = max(-sat, min(sat, u))
        if k % 200 == 199:
            target += 1


def pulse_to_rest(plant: Plant) -> float:
    plant.reset()
    t0 = time.perf_counter()
    plant.step(3 * plant.params.f_m, 1e-3)
    while not plant.step(0.0, 0.05).at_rest:
        pass
    return time.perf_counter() - t0


def main() -> dict:
    results = {"machine": {"cores": os.cpu_count(), "cpu": platform.processor() or platform.machine(),
                           "python": platform.python_version()}}
    for fmi in (2, 3):
        with Plant(DriveParams(), fmi_version=fmi) as plant:
            results[f"fmi{fmi}"] = {
                "raw_do_step_per_s": best_rate(lambda n: raw_do_step(plant, n), 200_000),
                "closed_loop_periods_per_s": best_rate(lambda n: closed_loop(plant, n), 100_000),
                "pulse_to_rest_s": min(pulse_to_rest(plant) for _ in range(20)),
            }
    out = Path(__file__).resolve().parent / "results" / "fmu_step.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    for key in ("fmi2", "fmi3"):
        r = results[key]
        print(f"{key}: raw doStep {r['raw_do_step_per_s']:,.0f}/s, closed loop {r['closed_loop_periods_per_s']:,.0f}"
              f" periods/s, nominal pulse rest-to-rest {r['pulse_to_rest_s'] * 1e6:.0f} us")
    print(f"written {out}")
    return results


if __name__ == "__main__":
    main()
