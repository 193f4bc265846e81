"""Benchmark of what a diagnosis spends most of its time on: simulating a log's training part through the FMU.

Times one simulation of the 7 s training part of a 10 s log at 5 kHz (35,000 samples of a torque-step input, from
the independent generator of tests/reference) for the base model (closed form) and for each library effect alone
(the general propagator; Stribeck and hysteresis also in the other shape the diagnosis checks them against), with the FMU's model evaluations per sample. Prints a table and writes
bench/results/log_simulation.json; ``--out`` names another file (e.g. to compare two builds of the FMU, one run per
checkout: the trajectories' SHA-256 tell whether two builds simulate bit for bit the same).

    python3 bench/log_simulation.py [--repeats 5] [--out FILE]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ident.fitting.identify import base_params  # noqa: E402
from ident.model.plant import Plant  # noqa: E402
from tests.ident_support import read_back  # noqa: E402
from tests.reference.generator.logs import diagnosis_case  # noqa: E402

SAMPLES = 35_000


def effects(base) -> dict[str, dict[str, float]]:
    """Each library effect alone at a size of the generator's order, and one mix of four."""
    return {
        "none (closed form)": {},
        "viscous motor": {"b_m": 1e-4 * base.f_m},
        "viscous load": {"b_l": 1e-2 * base.f_l},
        "asymmetric friction": {"friction_asymmetry": 0.1},
        "hardening": {"hardening": 0.5},
        "Stribeck": {"stribeck_ratio": 1.3, "stribeck_velocity": 1e-3},
        "Stribeck, exponential decay": {"stribeck_ratio": 1.3, "stribeck_velocity": 1e-3, "stribeck_shape": 1.0},
        "hysteresis": {"hysteresis_torque": 0.1 * base.f_l, "hysteresis_stiffness": 10 * base.K_s},
        "hysteresis, exponent 2": {"hysteresis_torque": 0.1 * base.f_l, "hysteresis_stiffness": 10 * base.K_s,
                                   "hysteresis_exponent": 2.0},
        "kinematic error 2/rev": {"kinematic_error": 1e-5, "kinematic_error_phase": 0.3},
        "kinematic error 2/rev + 4/rev": {"kinematic_error": 1e-5, "kinematic_error_4": 3e-6,
                                          "kinematic_error_4_phase": 1.0},
        "four at once": {"hysteresis_torque": 0.05 * base.f_l, "hysteresis_stiffness": 5 * base.K_s,
                         "stribeck_ratio": 0.5, "stribeck_velocity": 3e-4, "kinematic_error": 5e-6,
                         "hardening": 0.2},
    }


def main() -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "log_simulation.json")
    args = ap.parse_args()
    log = read_back(diagnosis_case(9101, "hardening", "medium", "steps", 10.0, rate_hz=5000.0))
    torque = log.motor_torque_Nm[:SAMPLES]
    base = base_params(log)
    rows = {}
    for name, values in effects(base).items():
        p = base.with_values(**values)
        plant = Plant(p)
        times = []
        try:
            for _ in range(args.repeats):
                plant.reset(p, q_m_start=0.0, q_l_start=0.0, v_m_start=0.0, v_l_start=0.0)
                t0 = time.perf_counter()
                q_m, q_l = plant.positions(torque, log.dt)
                times.append(time.perf_counter() - t0)
            evals = plant.model_evaluations() / SAMPLES   # counted since the last reset
        finally:
            plant.close()
        digest = hashlib.sha256(q_m.tobytes() + q_l.tobytes()).hexdigest()[:16]
        rows[name] = {"ms": 1e3 * statistics.median(times), "evaluations_per_sample": evals, "sha256": digest}
        print(f"{name:32s} {rows[name]['ms']:8.2f} ms  {evals:6.1f} evaluations/sample  {digest}", flush=True)
    out = {"machine": {"cores": os.cpu_count(), "cpu": platform.processor() or platform.machine(),
                       "python": platform.python_version()},
           "samples": SAMPLES, "repeats": args.repeats, "simulations": rows}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
