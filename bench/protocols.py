"""Benchmark of the protocols' compiled loops (issue 20; ident.protocols.compiled, fmu_build/c/protocols.c).

Targets on 2 cores: the 25-level friction sweep with N = 1000 in at most 1 s (goal: 15x a pure-Python exact
reference run serially); one nominal impulse resolution in at most 20 ms; the nominal linear resolution in at most
50 ms; ``paper-effects`` with its defaults in at most 20 s; Ctrl-C ends a compiled run within about a second.

Measured in one run, side by side: the compiled loops (default) and the Python loops (``loop="python"``) on the same
FMU; the share of the time spent inside the compiled loops (i.e. in the FMU's doSteps: the loop itself is a few
dozen instructions per step); the independent pure-Python reference (``tests/reference/event_driven.py``, scipy
DOP853 with located events) on a sample of the sweep's own pulses (its whole sweep would take about an hour), scaled
to the sweep by the number of pulses per amplitude; the Ctrl-C latency (SIGINT to KeyboardInterrupt) of a compiled
run, also in the slowest effects case. Wall times are medians of repeats; CPU times (``time.process_time``) are
given beside them because the machine is shared: the load average before and after is recorded.

Prints the figures and writes bench/results/protocols.json (protocols_quick.json with ``--quick``, not kept).
``python bench/protocols.py [--quick]`` (``--quick``: no paper-effects run, fewer repeats).
"""
from __future__ import annotations

import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from statistics import median
from typing import Any, Callable

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ident import DriveParams, impulse_experiment, impulse_resolution, linear_resolution  # noqa: E402
from ident.protocols import compiled  # noqa: E402
from ident.protocols.batch import run_batch  # noqa: E402
from ident.protocols.sweep import friction_levels, friction_sweep  # noqa: E402
from ident.studies.paper_effects import EFFECT_CASES, write_paper_effects  # noqa: E402
from tests.reference.event_driven import DriveSI, pulse_increments  # noqa: E402

TARGETS = {"sweep_25x1000_s": 1.0, "sweep_reference_ratio": 15.0, "impulse_resolution_s": 0.020,
           "linear_resolution_s": 0.050, "paper_effects_s": 20.0, "interrupt_s": 1.0}


def machine() -> dict[str, Any]:
    try:
        model = next(line.split(":", 1)[1].strip() for line in subprocess.run(
            ["lscpu"], capture_output=True, text=True).stdout.splitlines() if line.startswith("Model name"))
    except (OSError, StopIteration):
        model = platform.processor() or "unknown"
    return {"cpu_model": model, "cores": os.cpu_count(), "python": platform.python_version(),
            "machine": platform.machine(), "loadavg_start": os.getloadavg()}


def timed(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    c, t = time.process_time(), time.perf_counter()
    value = fn()
    return value, time.perf_counter() - t, time.process_time() - c


def repeat(fn: Callable[[], Any], n: int) -> dict[str, Any]:
    runs = [timed(fn)[1:] for _ in range(n)]
    return {"wall_s_median": median(r[0] for r in runs), "cpu_s_median": median(r[1] for r in runs),
            "wall_s": [r[0] for r in runs], "cpu_s": [r[1] for r in runs]}


def level_task(params: DriveParams) -> Any:
    """One level of the sweep (compiled loops), as a task for a process cluster."""
    return impulse_resolution(params, 1000)


def time_in_loops(fn: Callable[[], Any]) -> tuple[float, compiled.LoopStats]:
    """(thread CPU time of ``fn``, the work of the compiled loops inside it), for serial runs."""
    stats = compiled.loop_stats(reset=True)
    c = time.thread_time()
    fn()
    return time.thread_time() - c, stats


def reference_estimate(sweep: Any, per_amplitude: int = 2, op_pulses: int = 5) -> dict[str, Any]:
    """The reference integrator on the first pulses of every amplitude the compiled sweep ran (fresh from rest),
    scaled by the pulses the sweep ran at that amplitude."""
    sampled = total_pulses = 0
    sample_s = estimate_s = 0.0
    for r in sweep.results:
        p = r.params
        ref = DriveSI.from_nondim(K_star=p.K_star, J_l_star=p.J_l_star, f_l_star=p.f_l_star, J_m=p.J_m, f_m=p.f_m,
                                  r=p.r, arm_length=p.arm_length)
        width_star = r.width_s / ref.T_c
        runs = [(a, used, min(used, per_amplitude)) for a, _, used in r.median_tests]
        runs.append((r.operating_amplitude, r.n_pulses, min(r.n_pulses, op_pulses)))
        for amplitude, used, m in runs:
            t = time.perf_counter()
            pulse_increments(ref, amplitude, width_star, m)
            dt = time.perf_counter() - t
            sample_s += dt
            estimate_s += dt / m * used
            sampled += m
            total_pulses += used
    return {"sampled_pulses": sampled, "sweep_pulses": total_pulses, "sample_s": sample_s,
            "estimated_serial_s": estimate_s}


def interrupt_latency(run: Callable[[], Any], delay_s: float) -> float | None:
    """Seconds from a SIGINT sent ``delay_s`` after ``run`` started to KeyboardInterrupt; None if it ended first."""
    sent: list[float] = []

    def fire() -> None:
        time.sleep(delay_s)
        sent.append(time.perf_counter())
        os.kill(os.getpid(), signal.SIGINT)

    thread = threading.Thread(target=fire)
    thread.start()
    finished = False
    try:
        run()
        finished = True
        thread.join()   # the signal still comes: received here, it measures nothing
    except KeyboardInterrupt:
        thread.join()
        return None if finished else time.perf_counter() - sent[0]
    return None


def bench_single(nominal: DriveParams, reps: int) -> dict[str, Any]:
    """One nominal impulse resolution and one linear resolution, compiled (``reps`` times) and Python loops."""
    out = {"impulse_resolution": {"compiled": repeat(lambda: impulse_resolution(nominal, 1000), reps),
                                  "python": repeat(lambda: impulse_resolution(nominal, 1000, loop="python"), 3)},
           "linear_resolution": {"compiled": repeat(lambda: linear_resolution(nominal, 1000), reps),
                                 "python": repeat(lambda: linear_resolution(nominal, 1000, loop="python"), 2)}}
    for key, r in out.items():
        r["ratio_python_over_compiled"] = r["python"]["wall_s_median"] / r["compiled"]["wall_s_median"]
        print(f"{key}: compiled {r['compiled']['wall_s_median'] * 1e3:.1f} ms wall "
              f"({r['compiled']['cpu_s_median'] * 1e3:.1f} ms CPU), python loop "
              f"{r['python']['wall_s_median'] * 1e3:.1f} ms: {r['ratio_python_over_compiled']:.1f}x", flush=True)
    return out


def bench_sweep(nominal: DriveParams, reps: int) -> dict[str, Any]:
    """The 25-level sweep, N = 1000: compiled on the default 2 threads, serially, the Python loops serially and on
    Dask processes (the path before issue 20), the FMU's share, and the reference integrator's estimate."""
    def sweep_fn() -> Any:
        return friction_sweep(nominal, 25, 1000)   # the default: compiled loops on Dask threads

    sweep = sweep_fn()
    s: dict[str, Any] = {"compiled_threads": repeat(sweep_fn, reps)}
    s["compiled_serial"] = repeat(lambda: friction_sweep(nominal, 25, 1000, workers=0), 1)
    s["python_serial"] = repeat(lambda: friction_sweep(nominal, 25, 1000, workers=0, loop="python"), 1)
    s["python_dask_processes"] = repeat(lambda: friction_sweep(nominal, 25, 1000, loop="python"), 1)
    tasks = [nominal.with_values(f_l_star=float(f)) for f in friction_levels(25)]
    s["compiled_dask_processes"] = repeat(lambda: run_batch(level_task, tasks, workers=2), 1)   # cluster start-up
    cpu, stats = time_in_loops(lambda: friction_sweep(nominal, 25, 1000, workers=0))
    s.update(serial_thread_cpu_s=cpu, inside_compiled_loops_s=stats.cpu_s, do_steps=stats.do_steps,
             c_calls=stats.calls)
    s["pulses"] = sum(sum(n for _, _, n in r.median_tests) + r.n_pulses for r in sweep.results)
    s["reference"] = reference_estimate(sweep)
    best = s["compiled_threads"]["wall_s_median"]
    s["ratio_python_serial"] = s["python_serial"]["wall_s_median"] / best
    s["ratio_reference_serial"] = s["reference"]["estimated_serial_s"] / best
    s["ratio_issue_reference_28s"] = 28.0 / best
    print(f"25-level sweep, N = 1000 ({s['pulses']:,} pulses, {stats.do_steps:,} doSteps): compiled on 2 threads "
          f"{best:.2f} s wall ({s['compiled_threads']['cpu_s_median']:.2f} s CPU), serial "
          f"{s['compiled_serial']['wall_s_median']:.2f} s; Python loop serial {s['python_serial']['wall_s_median']:.2f}"
          f" s ({s['ratio_python_serial']:.1f}x), on Dask processes {s['python_dask_processes']['wall_s_median']:.2f}"
          f" s; compiled on a local Dask cluster of 2 processes {s['compiled_dask_processes']['wall_s_median']:.2f} s"
          f" (start-up included); {stats.cpu_s / cpu:.0%} of the serial CPU time inside the compiled loops (the "
          f"FMU's doSteps)")
    print(f"reference (event_driven.py, DOP853) estimated {s['reference']['estimated_serial_s']:.0f} s serially "
          f"from {s['reference']['sampled_pulses']} sampled pulses: {s['ratio_reference_serial']:.0f}x; the issue's "
          f"28 s closed-form Python integrator (not in the repository): {s['ratio_issue_reference_28s']:.1f}x",
          flush=True)
    return s


def bench_interrupts(nominal: DriveParams) -> dict[str, Any]:
    heavy = next(c for c in EFFECT_CASES if c.name == "hysteresis_fl").params(nominal, 0.01)
    out = {"impulse_experiment_nominal": [interrupt_latency(lambda: impulse_experiment(nominal, 1.2, 10**7), d)
                                          for d in (0.3, 0.6, 0.9)],
           "hysteresis_fl_at_0.01": [interrupt_latency(lambda: impulse_resolution(heavy, 3000), d) for d in (0.5, 1.0)],
           "sweep_threads_n20000": [interrupt_latency(lambda: friction_sweep(nominal, 25, 20000), 1.0)]}
    print(f"Ctrl-C latency [s]: {out}", flush=True)
    return out


def bench_paper_effects() -> dict[str, Any]:
    with tempfile.TemporaryDirectory() as tmp:
        (sweep_fx, _), wall, cpu = timed(lambda: write_paper_effects(Path(tmp) / "paper_effects"))
    df = sweep_fx.to_frame()
    out = {"wall_s": wall, "cpu_s": cpu, "tasks": len(df), "task_time_s_total": float(df["elapsed_s"].sum()),
           "task_time_s_by_case": df.groupby("case", sort=False)["elapsed_s"].sum().to_dict()}
    print(f"paper-effects defaults: {wall:.1f} s wall ({cpu:.1f} s CPU, {len(df)} tasks, "
          f"{out['task_time_s_total']:.1f} s of task time)", flush=True)
    return out


def main(quick: bool = False) -> dict[str, Any]:
    nominal = DriveParams()
    out: dict[str, Any] = {"machine": machine(), "targets": TARGETS}
    impulse_resolution(nominal, 10)   # build / load the FMU and the loops once
    out.update(bench_single(nominal, 3 if quick else 7))
    out["sweep_25x1000"] = bench_sweep(nominal, 3 if quick else 5)
    out["interrupt_s"] = bench_interrupts(nominal)
    if not quick:
        out["paper_effects"] = bench_paper_effects()
    out["machine"]["loadavg_end"] = os.getloadavg()
    path = ROOT / "bench" / "results" / ("protocols_quick.json" if quick else "protocols.json")
    path.parent.mkdir(exist_ok=True)
    path.write_text(json.dumps(out, indent=2, default=float))
    print(f"written {path}")
    return out


if __name__ == "__main__":
    main(quick="--quick" in sys.argv[1:])
