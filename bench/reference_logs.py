"""Generation time of the independent reference logs (tests/reference/generator), by excitation and by effect.

- identification logs (clean): every excitation kind x ``n_seeds`` seeds at the drawn sample rate (1-10 kHz), for
  4 s and 10 s logs: CPU time (process_time, little affected by other load on a shared machine) and wall time per
  log, CPU microseconds per sample;
- diagnosis logs: every effect and shape variant (and the two outside the library) on one drive and the default
  design: the first magnitude class (clean run + the weak-magnitude search + the log + its SNR run) and a further
  class (the search cached: the log + its SNR run), with the engine used and the simulations the search needed.

Prints a summary and writes bench/results/reference_logs.json. Usage:
python bench/reference_logs.py [n_seeds] [durations, comma-separated]
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.reference.generator import logs
from tests.reference.generator.effects import (
    LIBRARY_EFFECTS,
    OUTSIDE_LIBRARY_EFFECTS,
    VARIANTS,
)

DIAGNOSIS_SEED = 5102


def identification_times(n_seeds: int, duration_s: float) -> list[dict]:
    rows = []
    for kind in logs.IDENTIFICATION_KINDS + ("mix",):
        for i in range(n_seeds):
            seed = 6001 + 10 * logs.IDENTIFICATION_KINDS.index(kind) + i if kind != "mix" else 6101 + i
            t0, c0 = time.perf_counter(), time.process_time()
            g = logs.identification_case(seed, kind, duration_s=duration_s)
            wall, cpu = time.perf_counter() - t0, time.process_time() - c0
            rows.append({"kind": kind, "seed": seed, "duration_s": duration_s, "rate_hz": g.truth.sample_rate_hz,
                         "samples": int(g.time_s.size), "wall_s": wall, "cpu_s": cpu,
                         "us_per_sample": 1e6 * cpu / g.time_s.size, "engine": g.truth.engine})
        sel = [r for r in rows if r["kind"] == kind]
        print(f"  {kind:14s} {duration_s:4.0f} s logs: CPU median {statistics.median(r['cpu_s'] for r in sel):5.2f} s, "
              f"max {max(r['cpu_s'] for r in sel):5.2f} s (wall median {statistics.median(r['wall_s'] for r in sel):5.2f}"
              f" s), median {statistics.median(r['us_per_sample'] for r in sel):5.1f} CPU us/sample", flush=True)
    return rows


def diagnosis_times(duration_s: float) -> list[dict]:
    rows = []
    for effect in LIBRARY_EFFECTS + OUTSIDE_LIBRARY_EFFECTS:
        for variant in VARIANTS.get(effect, (None,)):
            logs.clear_caches()  # a cold start for each effect: count the clean run too
            row = {"effect": effect, "variant": variant, "duration_s": duration_s}
            for label, cls in (("first_class_s", "weak"), ("further_class_s", "strong")):
                t0, c0 = time.perf_counter(), time.process_time()
                if effect in LIBRARY_EFFECTS:
                    g = logs.diagnosis_case(DIAGNOSIS_SEED, effect, cls, "default", duration_s, variant=variant)
                else:
                    g = logs.outside_library_case(DIAGNOSIS_SEED, effect, cls, "default", duration_s)
                row[label] = time.process_time() - c0
                row[label.replace("_s", "_wall_s")] = time.perf_counter() - t0
                row[f"snr_{cls}"] = g.truth.snr[effect]
            row.update(engine=g.truth.engine, rate_hz=g.truth.sample_rate_hz,
                       search_runs=logs.weak_search(DIAGNOSIS_SEED, effect, "default", duration_s,
                                                    variant if effect in LIBRARY_EFFECTS else None)[2])
            rows.append(row)
            print(f"  {effect:20s} {variant or '':16s} {row['engine']:12s} CPU: first class {row['first_class_s']:6.2f} s "
                  f"({row['search_runs']} search runs), further class {row['further_class_s']:5.2f} s, "
                  f"SNR weak {row['snr_weak']:.2f}, strong {row['snr_strong']:.1f}", flush=True)
    return rows


def main(n_seeds: int = 4, durations: tuple[float, ...] = (4.0, 10.0)) -> dict:
    out = {"machine": {"nproc": os.cpu_count(), "python": platform.python_version(), "cpu": platform.processor(),
                       "load_average_at_start": os.getloadavg()},
           "identification": [], "diagnosis": []}
    for duration in durations:
        print(f"identification logs, {duration:g} s:")
        out["identification"] += identification_times(n_seeds, duration)
    for duration in durations:
        print(f"diagnosis logs, {duration:g} s, seed {DIAGNOSIS_SEED}, default design:")
        out["diagnosis"] += diagnosis_times(duration)
    path = Path(__file__).with_name("results") / "reference_logs.json"
    path.write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 4
    d = tuple(float(x) for x in sys.argv[2].split(",")) if len(sys.argv) > 2 else (4.0, 10.0)
    main(n, d)
