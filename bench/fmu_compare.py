"""Bit-for-bit comparison of this FMU with a baseline FMU (e.g. one built from an older commit): every real output,
the encoder count and both stuck flags after every step, over the test scenarios, every effect alone and 150 random
drives, for FMI 2 and 3. Prints the runs that differ; writes bench/results/fmu_compare.json.

    python3 bench/fmu_compare.py --baseline2 OLD2.fmu --baseline3 OLD3.fmu
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fmu_build import build_fmu  # noqa: E402
from ident import DriveParams, Plant  # noqa: E402

OUT = ("q_m", "q_l", "v_m", "v_l", "spring_torque", "input_work", "friction_work", "deflection",
       "hysteresis_state", "motor_friction_torque", "load_friction_torque")
NOM = DriveParams()
ALL_ON = dict(b_m=1e-4, b_l=1.0, stribeck_ratio=0.5, stribeck_velocity=5e-4, friction_asymmetry=0.2,
              hardening=3e6, hysteresis_torque=3e-3, hysteresis_stiffness=1e4, kinematic_error=5e-5,
              kinematic_error_phase=0.3, viscous_asymmetry=0.3)


def run(path, fmi, params, init, schedule):
    with Plant(params, fmi_version=fmi, fmu_path=path, **init) as p:
        rows = []
        for torque, dt in schedule:
            p.step(torque, dt)
            rows.append(p.trajectory(np.zeros(0), 1e-3, OUT)[0])
            s = p.sample()
            rows[-1] = np.append(rows[-1], [s.encoder_count, s.motor_stuck, s.load_stuck])
        return np.array(rows)


def scenarios(rng):
    f = NOM.f_m
    yield "driven_1", NOM, {}, [(1.5 * f, 1.0)]
    yield "driven_1000", NOM, {}, [(1.5 * f, 1e-3)] * 1000
    yield "coast_1", NOM, dict(v_m_start=2.0), [(0.0, 1.0)]
    yield "coast_1000", NOM, dict(v_m_start=2.0), [(0.0, 1e-3)] * 1000
    yield "stickslip_1", NOM, dict(q_l_start=-2e-5), [(0.95 * f, 1.0)]
    yield "stickslip_1000", NOM, dict(q_l_start=-2e-5), [(0.95 * f, 1e-3)] * 1000
    yield "pulses", NOM, {}, [(0.03, 1e-3)] + [(0.0, 1e-3)] * 50 + [(-0.025, 1e-3)] + [(0.0, 1e-3)] * 50
    pe = NOM.with_values(**ALL_ON)
    q_eq = ALL_ON["kinematic_error"] * math.sin(ALL_ON["kinematic_error_phase"])
    for dt in (1e-4, 1e-3):
        sched = []
        for k in range(int(round(0.15 / dt))):
            t = k * dt
            amp = 0.0
            for t0, a in ((0.0, 3.0), (0.03, -4.0), (0.05, 2.5), (0.09, -2.2), (0.12, 5.0)):
                if t0 - 1e-12 <= t < t0 + 1e-3 - 1e-12:
                    amp = a * f
            sched.append((amp, dt))
        yield f"all_on_{dt}", pe, dict(q_l_start=q_eq), sched
    for name, val in ALL_ON.items():
        if name in ("stribeck_velocity", "hysteresis_stiffness", "kinematic_error_phase"):
            continue
        extra = {name: val}
        if name == "hysteresis_torque":
            extra["hysteresis_stiffness"] = 1e4
        p = NOM.with_values(**extra)
        sched = [(float(rng.uniform(-4, 4) * f), float(10 ** rng.uniform(-4, -2))) for _ in range(60)]
        yield f"effect_{name}", p, {}, sched
    for case in range(150):
        vals = {}
        for k in ("J_m", "f_m", "K_s", "J_l", "f_l"):
            vals[k] = float(getattr(NOM, k) * 10 ** rng.uniform(-2, 2))
        vals["r"] = float(10 ** rng.uniform(-3, 0))
        if rng.random() < 0.3:
            vals.update({k: v * 10 ** rng.uniform(-1, 1) for k, v in ALL_ON.items()
                         if rng.random() < 0.4 and k not in ("friction_asymmetry", "viscous_asymmetry", "kinematic_error_phase")})
        p = NOM.with_values(**vals)
        init = dict(q_l_start=float(rng.uniform(-1e-4, 1e-4)), v_m_start=float(rng.uniform(-0.1, 0.1)))
        sched = [(float(rng.uniform(-5, 5) * vals["f_m"] * 10 ** rng.uniform(-1, 1)), float(10 ** rng.uniform(-6, -1)))
                 for _ in range(5)]
        yield f"random_{case}", p, init, sched


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline2", required=True, type=Path)
    parser.add_argument("--baseline3", required=True, type=Path)
    args = parser.parse_args()
    old = {2: args.baseline2, 3: args.baseline3}
    new = {2: build_fmu(2), 3: build_fmu(3)}
    differing = []
    rng = np.random.default_rng(7)  # the random drives: fixed, so that the comparison can be repeated
    n = diff = 0
    for name, p, init, sched in scenarios(rng):
        for fmi in (2, 3):
            try:
                a = run(old[fmi], fmi, p, init, sched)
            except Exception as exc:
                a = repr(exc)[:60]
            try:
                b = run(new[fmi], fmi, p, init, sched)
            except Exception as exc:
                b = repr(exc)[:60]
            n += 1
            same = (isinstance(a, str) and isinstance(b, str)) or (
                not isinstance(a, str) and not isinstance(b, str) and np.array_equal(a, b, equal_nan=True))
            if not same:
                diff += 1
                differing.append({"scenario": name, "fmi": fmi, "baseline": a if isinstance(a, str) else "ok",
                                  "now": b if isinstance(b, str) else "ok"})
                print("DIFF", name, fmi, a if isinstance(a, str) else "", b if isinstance(b, str) else "")
    print(f"{n} runs compared, {diff} differ")
    out = Path(__file__).resolve().parent / "results" / "fmu_compare.json"
    out.write_text(json.dumps({"runs": n, "differ": diff, "differing": differing}, indent=2) + "\n")


if __name__ == "__main__":
    main()
