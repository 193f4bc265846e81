"""How fast Ctrl-C and SIGTERM stop the long commands, and what they leave behind.

For each command (sweep, study, identify, predict, diagnose) and each signal, the command is started in a child
process with a private TMPDIR, the signal is sent after a delay (the work is under way by then), and the script
records the time from the signal to the exit, the exit code, the last stderr line, and any files left in TMPDIR or
beside --out. Prints a table and writes bench/results/interrupts.json.

    python3 bench/interrupts.py [--delays 3 6] [--repeat 2]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def make_log(folder: Path) -> Path:
    from ident.fitting.logs import write_log
    from ident.fitting.synthetic import synthetic_log
    from ident.model.params import DriveParams

    path, _ = write_log(synthetic_log(DriveParams(), duration_s=10.0), folder / "run.csv")
    return path


def commands(log: Path, out: Path) -> dict[str, list[str]]:
    # N = 20,000: the compiled protocol loops finish the N = 1000 sweep within a few seconds, before the signal
    return {"sweep": ["sweep", "--levels", "25", "--pulses", "20000", "--out", str(out)],
            "study": ["study", "--out", str(out)],
            "identify": ["identify", str(log), "--json"],
            "predict": ["predict", str(log), "--json"],
            "diagnose": ["diagnose", str(log), "--out", str(out), "--json"]}


def one(name: str, argv: list[str], sig: int, delay: float, work: Path) -> dict:
    tmp = Path(tempfile.mkdtemp(dir=work, prefix="tmp-"))
    env = {**os.environ, "TMPDIR": str(tmp), "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "ident", *argv], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, env=env, cwd=work)
    time.sleep(delay)
    finished_early = proc.poll() is not None
    t0 = time.perf_counter()
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    latency = time.perf_counter() - t0
    out = Path(argv[argv.index("--out") + 1]) if "--out" in argv else None
    left = [p.name for p in tmp.iterdir()] + ([p.name for p in out.parent.iterdir() if p.name.startswith(f".{out.name}")]
                                            if out is not None else [])
    return {"command": name, "signal": signal.Signals(sig).name, "delay_s": delay, "latency_s": round(latency, 3),
            "exit": proc.returncode, "finished_before_signal": finished_early,
            "last_line": (err.strip().splitlines() or [""])[-1][:160], "traceback": "Traceback" in err,
            "left_behind": left, "out_written": bool(out is not None and out.exists())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--delays", type=float, nargs="+", default=[3.0, 6.0])
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    # A terminal's Ctrl-C reaches a process whose SIGINT is not ignored. A script started in the background by a
    # non-interactive shell inherits SIGINT ignored, and so would the commands it starts (which then, rightly, keep
    # ignoring it): give them the default disposition, as a terminal does.
    signal.signal(signal.SIGINT, signal.default_int_handler)
    work = Path(tempfile.mkdtemp(prefix="hdrive-bench-interrupts-"))
    log = make_log(work)
    rows = []
    runs = 0
    for name in commands(log, work / "out"):
        for sig in (signal.SIGINT, signal.SIGTERM):
            for delay in args.delays:
                for _ in range(args.repeat):
                    runs += 1   # a fresh --out per run: a finished run's folder must not count for the next
                    row = one(name, commands(log, work / f"out{runs}")[name], sig, delay, work)
                    rows.append(row)
                    print(f"{name:9s} {row['signal']:7s} after {delay:4.1f} s: exit {row['exit']:4d} in "
                          f"{row['latency_s']:6.2f} s, left {row['left_behind'] or 'nothing'}; {row['last_line']}",
                          flush=True)
    result = {"machine": {"cpus": os.cpu_count(), "processor": platform.processor() or platform.machine(),
                          "load_average": os.getloadavg()}, "runs": rows,
              "max_latency_s": max(r["latency_s"] for r in rows)}
    path = ROOT / "bench" / "results" / "interrupts.json"
    path.write_text(json.dumps(result, indent=2))
    print(f"max latency {result['max_latency_s']:.2f} s; wrote {path}")


if __name__ == "__main__":
    main()
