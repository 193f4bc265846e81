"""Benchmark of the FMU's worst cases (issue 17): degenerate doSteps, the cost of one model evaluation, and the
randomized FMI-call harness's worst call. Prints a table and writes bench/results/fmu_robustness.json.

Target: every doStep within 1 s of CPU, whatever the step size or state (the FMU's work budget of
``HD_WORK_BUDGET`` model evaluations per doStep is what guarantees it; this measures the CPU that budget costs).

    python3 bench/fmu_robustness.py [--baseline OLD.fmu] [--timeout 60] [--harness-calls 5000] [--seeds 3]

``--baseline`` times the same degenerate cases on another FMI 2 FMU (e.g. one built from an older commit), each in
a child process cut off after ``--timeout`` seconds (reported as "> timeout").
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fmu_build import build_fmu  # noqa: E402
from tests.fmi_harness import Api, run as run_harness  # noqa: E402

VR = {"b_m": 100, "f_m": 2, "f_l": 5, "q_l_start": 21, "motor_torque": 30, "stribeck_ratio": 102,
      "stribeck_velocity": 103, "hardening": 105}
# name: (parameters, motor torque [N m], step [s]) - the cases of issue 17, and the harshest found beside them.
CASES = {
    "effect, slipping at v = 0, subnormal step": (dict(b_m=1e-4), 0.03, 5e-324),
    "base model, Coulomb ringing, h = 1e20 s": (dict(f_m=1e6, f_l=1e-9, q_l_start=1e-3), 0.0, 1e20),
    "Stribeck + hardening 1e10 + deflection 1e-2, 1 ms": (
        dict(stribeck_ratio=0.5, stribeck_velocity=5e-4, hardening=1e10, q_l_start=-1e-2), 0.0, 1e-3),
    "Stribeck + hardening 1e12 + deflection 1e-1, 1 ms": (
        dict(stribeck_ratio=0.5, stribeck_velocity=5e-4, hardening=1e12, q_l_start=-1e-1), 0.0, 1e-3),
    "effect, h = 1e20 s": (dict(b_m=1e-4), 0.03, 1e20),
}


def time_case(fmu: Path, name: str) -> dict:
    """One doStep of ``name`` on a fresh FMI 2 instance: status, CPU seconds, the FMU's message."""
    import tempfile

    params, torque, h = CASES[name]
    with tempfile.TemporaryDirectory(prefix="hdrive-bench-") as tmp:
        api = Api(fmu, 2, Path(tmp))
        c = api.instantiate(True)
        for key, value in params.items():
            api.reals(c, [VR[key]], [value])
        api.enter_init(c, 0.0)
        api.simple(c, "ExitInitializationMode")
        api.reals(c, [VR["motor_torque"]], [torque])
        api.debug_logging(c, True, [])  # a new FMU reports its work; an old one ignores the categories
        api.log.clear()
        t0 = time.process_time()
        status = api.do_step(c, 0.0, h)
        cpu = time.process_time() - t0
        return {"status": status, "cpu_s": cpu, "message": api.log[-1][2] if api.log else ""}


def time_case_in_child(fmu: Path, name: str, timeout_s: float) -> dict:
    cmd = [sys.executable, __file__, "--one", name, "--fmu", str(fmu)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"status": None, "cpu_s": None, "message": f"> {timeout_s:g} s (cut off)"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def cost_per_evaluation() -> list[dict]:
    """CPU per model evaluation (the FMU's own count) for steps that spend the whole budget or most of it."""
    out = []
    for name in list(CASES)[1:4]:
        r = time_case(build_fmu(fmi_version=2), name)
        m = re.search(r"(\d+) model evaluations \(|needs more than the (\d+) model evaluations", r["message"])
        work = int(m[1] or m[2]) if m else 0
        if work and r["cpu_s"]:
            out.append({"case": name, "evaluations": work, "ns_per_evaluation": 1e9 * r["cpu_s"] / work})
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--baseline", type=Path, help="an older FMI 2 FMU to time the same cases on")
    parser.add_argument("--timeout", type=float, default=60.0)
    parser.add_argument("--harness-calls", type=int, default=5000)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--one", help=argparse.SUPPRESS)
    parser.add_argument("--fmu", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        print(json.dumps(time_case(args.fmu, args.one)))
        return 0
    current = build_fmu(fmi_version=2)
    result: dict = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
                    "cases": {}, "harness": []}
    for name in CASES:
        row = {"now": time_case_in_child(current, name, args.timeout)}
        if args.baseline:
            row["baseline"] = time_case_in_child(args.baseline, name, args.timeout)
        result["cases"][name] = row
        print(name, json.dumps(row))
    result["cost_per_evaluation"] = cost_per_evaluation()
    print(json.dumps(result["cost_per_evaluation"]))
    for fmi in (2, 3):
        for effects in (False, True):
            for seed in range(args.seeds):
                s = run_harness(fmi, effects, seed, args.harness_calls).to_dict()
                result["harness"].append(s)
                print(f"harness FMI {fmi} effects {effects} seed {seed}: worst call {s['worst_cpu_s']:.3f} s CPU "
                      f"({s['worst_call']}), worst accepted step {s['worst_step_work']} evaluations, "
                      f"{s['steps_ok']} steps taken, {s['steps_refused']} refused")
    worst = max(result["harness"], key=lambda s: s["worst_cpu_s"])
    result["harness_worst_cpu_s"] = worst["worst_cpu_s"]
    print(f"worst call over {sum(s['calls'] for s in result['harness'])} harness calls: {worst['worst_cpu_s']:.3f} s")
    out = ROOT / "bench" / "results" / "fmu_robustness.json"
    out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
