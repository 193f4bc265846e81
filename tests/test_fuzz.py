"""Seeded fuzzing of what users hand the tool: logs and sidecars mutated at random (read with ``read_log``), and
command lines built at random (run through ``ident.cli.main``). Every case must end in a clean, named error or a
correct result: never a traceback or an internal error, never a hang (a per-case time limit), never a half-written
output folder or a staging folder left beside it. A few hundred cases in the default run, thousands in the slow
suite (``pytest -m slow tests/test_fuzz.py``)."""
from __future__ import annotations

import contextlib
import io
import json
import math
import signal
from pathlib import Path

import numpy as np
import pytest

from ident import DriveLog, read_log
from ident.cli import main
from ident.fitting.logs import LogError

META = {"r": 0.01, "J_m_kgm2": 2e-5, "f_m_Nm": 0.01, "arm_length_m": 0.3, "encoder_counts_per_rev": 12566,
        "sample_rate_hz": 1000.0}
HEADER = ["time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad"]
CASE_LIMIT_S = 60.0       # a case still running after this is a hang
JUNK = ["", " ", "nan", "NaN", "inf", "-inf", "1e400", "1e300", "-1e300", "abc", "0x10", "1,5", "--1", "1e", "None",
        "true", "١٢", "1.0.0", "\t", "'3'"]
META_JUNK = [None, 0, -1, 1e300, -1e-300, "x", "", True, False, [], {}, [1.0], float("nan"), 2**40, 0.5, 1e-9]


class Hang(Exception):
    pass


@contextlib.contextmanager
def time_limit(seconds: float):
    def alarm(signum, frame):
        raise Hang(f"case still running after {seconds} s")
    previous = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def base_rows(rng: np.random.Generator, n: int = 40) -> list[list[str]]:
    t = np.arange(n) / META["sample_rate_hz"]
    tau = rng.choice([0.0, 0.02, -0.02], n)
    q_m = np.floor(np.cumsum(rng.normal(0, 1e-3, n)) / (2 * math.pi / 12566)) * (2 * math.pi / 12566)
    q_l = 0.01 * q_m + rng.normal(0, 1e-8, n)
    return [[repr(float(x)) for x in row] for row in zip(t, tau, q_m, q_l)]


# ------------------------------------------------------------------------------------------ log mutations ------

def mutate_csv(rng, header: list[str], rows: list[list[str]]) -> tuple[str, str, bool]:
    """A mutated CSV text, the mutation's name, and whether it keeps the data identical (benign)."""
    header, rows = list(header), [list(r) for r in rows]
    kind = rng.choice(["cell", "cell", "drop_row", "dup_row", "swap_rows", "drop_column", "rename_header",
                       "extra_column", "truncate", "bom", "crlf", "empty", "header_only", "shuffle_columns",
                       "repeat_column", "short_row", "long_row", "spaces"])
    if kind == "cell":
        rows[rng.integers(len(rows))][rng.integers(len(header))] = str(rng.choice(JUNK))
    elif kind == "drop_row":
        del rows[rng.integers(1, len(rows) - 1)]
    elif kind == "dup_row":
        k = int(rng.integers(len(rows)))
        rows.insert(k, rows[k])
    elif kind == "swap_rows":
        a, b = rng.choice(len(rows), 2, replace=False)
        rows[a], rows[b] = rows[b], rows[a]
    elif kind == "drop_column":
        j = int(rng.integers(len(header)))
        header.pop(j)
        for r in rows:
            r.pop(j)
    elif kind == "rename_header":
        header[rng.integers(len(header))] = str(rng.choice(["Time", "torque", "", "motor_pos", "x"]))
    elif kind == "extra_column":
        header.append("temperature_C")
        for r in rows:
            r.append("21.5")
    elif kind == "repeat_column":
        j = int(rng.integers(len(header)))
        header.append(header[j])
        for r in rows:
            r.append(r[j])
    elif kind == "shuffle_columns":
        order = rng.permutation(len(header))
        header = [header[j] for j in order]
        rows = [[r[j] for j in order] for r in rows]
    elif kind == "short_row":
        rows[rng.integers(len(rows))].pop()
    elif kind == "long_row":
        rows[rng.integers(len(rows))].append("1")
    text = "\n".join([",".join(header), *(",".join(r) for r in rows)]) + "\n"
    if kind == "truncate":
        text = text[: int(rng.integers(1, len(text) - 1))]
    elif kind == "bom":
        text = "\ufeff" + text
    elif kind == "crlf":
        text = text.replace("\n", "\r\n")
    elif kind == "empty":
        text = ""
    elif kind == "header_only":
        text = ",".join(header) + "\n"
    elif kind == "spaces":
        text = text.replace(",", ", ")
    return text, kind, kind in ("extra_column", "bom", "crlf", "shuffle_columns", "spaces")


def mutate_meta(rng) -> tuple[str, str, bool]:
    meta = dict(META)
    kind = rng.choice(["value", "value", "drop", "extra", "bad_json", "not_object", "units_ok", "units_bad", "kind",
                       "none"])
    if kind == "value":
        meta[str(rng.choice(list(META)))] = META_JUNK[rng.integers(len(META_JUNK))]
    elif kind == "drop":
        meta.pop(str(rng.choice(list(META))))
    elif kind == "extra":
        meta["operator"] = "night shift"
    elif kind == "units_ok":
        meta["units"] = {"time_s": "s", "motor_torque_Nm": "N m", "motor_pos_rad": "rad", "load_pos_rad": "rad"}
    elif kind == "units_bad":
        meta["units"] = {"load_pos_rad": str(rng.choice(["deg", "mrad", "um", ""]))}
    elif kind == "kind":
        meta["kind"] = str(rng.choice(["linear", "rotary", "spherical", ""]))
    if kind == "bad_json":
        return json.dumps(meta)[:-3], kind, False
    if kind == "not_object":
        return json.dumps([meta]), kind, False
    return json.dumps(meta), kind, kind in ("extra", "units_ok", "none")


def check_log_case(rng, folder: Path, rows: list[list[str]], reference: DriveLog) -> str:
    text, csv_kind, csv_benign = mutate_csv(rng, HEADER, rows)
    meta, meta_kind, meta_benign = mutate_meta(rng) if rng.random() < 0.5 else (json.dumps(META), "none", True)
    path = folder / "run.csv"
    path.write_text(text, encoding="utf-8")
    (folder / "run.json").write_text(meta)
    try:
        with time_limit(CASE_LIMIT_S):
            log = read_log(path)
    except LogError as exc:
        message = str(exc)
        assert str(folder) in message, f"{csv_kind}/{meta_kind}: the error does not name the file: {message}"
        return "error"
    if csv_benign and meta_benign:
        for name in ("time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad"):
            np.testing.assert_array_equal(getattr(log, name), getattr(reference, name), err_msg=csv_kind)
    else:   # accepted although changed: it must still be a usable log
        assert log.n >= 10 and np.all(np.diff(log.time_s) > 0) and np.all(np.isfinite(log.motor_torque_Nm))
    return "ok"


def run_log_fuzz(seed: int, n: int, folder: Path) -> dict[str, int]:
    rng = np.random.default_rng(seed)
    rows = base_rows(rng)
    (folder / "base.csv").write_text("\n".join([",".join(HEADER), *(",".join(r) for r in rows)]) + "\n")
    reference = read_log(folder / "base.csv", META)
    counts = {"error": 0, "ok": 0}
    for _ in range(n):
        counts[check_log_case(rng, folder, rows, reference)] += 1
    return counts


# ------------------------------------------------------------------------------------------ command lines ------

NUMBERS = ["-1", "0", "1", "2", "3", "nan", "inf", "-inf", "1e300", "2.5", "x", "", "-0", "1e-300"]


def random_argv(rng, folder: Path) -> tuple[list[str], Path | None]:
    """A command line over every command, with options drawn from bad and small good values, so that a case that
    passes the checks still finishes in seconds."""
    out = folder / str(rng.choice(["out", "existing_file", "existing_dir", "nested/deeper/out"]))
    log = str(folder / str(rng.choice(["still.csv", "missing.csv", "still.json", "."])))
    cmd = str(rng.choice(["resolution", "sweep", "study", "identify", "predict", "diagnose", "demo", "paper-effects",
                          "emps-report", "build-fmu"]))
    small = lambda: str(rng.choice(NUMBERS))  # noqa: E731
    argv = {"resolution": ["resolution", "--controller", str(rng.choice(["impulse", "linear", "pd"])),
                           "--pulses", str(rng.choice(["0", "2", "-3", "x"])), "--steps", str(rng.choice(["0", "2"])),
                           "--eps1-um", small()],
            "sweep": ["sweep", "--levels", small(), "--pulses", str(rng.choice(["0", "2", "nan"])), "--workers",
                      str(rng.choice(["-1", "0", "x"])), "--out", str(out)],
            "study": ["study", "--levels", small(), "--pulses", str(rng.choice(["0", "-2"])), "--steps", small(),
                      "--workers", "0", "--out", str(out)],
            "identify": ["identify", log, "--json"],
            "predict": ["predict", log, "--draws", small(), "--workers", "0"],
            "diagnose": ["diagnose", log, "--out", str(out), "--max-effects", small(), "--workers", "0"],
            "demo": ["demo", "--out", str(out), "--pulses", str(rng.choice(["0", "-1", "1", "x"])), "--amplitude",
                     small()],
            "paper-effects": ["paper-effects", "--out", str(out), "--levels", small(), "--pulses",
                              str(rng.choice(["0", "-1"])), "--workers", "0"],
            "emps-report": ["emps-report", "--out", str(out), "--data", str(folder)],
            "build-fmu": ["build-fmu", "--out", str(out), "--fmi", str(rng.choice(["1", "4", "x"]))]}[cmd]
    if rng.random() < 0.3 and cmd in ("resolution", "sweep", "study", "demo", "paper-effects"):
        argv += ["--param", f"{rng.choice(['f_m', 'K_s', 'r', 'J_l', 'nope', 'f_l_star', ''])}={small()}"]
    return argv, out if "--out" in argv else None


def check_cli_case(rng, folder: Path) -> int:
    argv, out = random_argv(rng, folder)
    before = sorted(p.name for p in folder.iterdir())
    stderr = io.StringIO()
    try:
        with time_limit(CASE_LIMIT_S), contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    except SystemExit as exc:   # argparse refuses an option's type or choice: usage and exit 2
        code = exc.code
    err = stderr.getvalue()
    assert code in (0, 2), f"{argv}: exit {code}: {err[-500:]}"
    assert "Traceback" not in err and "internal error" not in err, f"{argv}: {err[-800:]}"
    if code == 2:
        assert err.strip(), f"{argv}: exit 2 without a message"
        after = sorted(p.name for p in folder.iterdir())
        assert after == before, f"{argv}: left {set(after) - set(before)} behind"
        if out is not None and out.name == "existing_dir":
            assert list(out.iterdir()) == [], f"{argv}: wrote into --out although it failed"
    return code


def cli_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "cli"
    folder.mkdir()
    rows = [[repr(k / 1000), "0.0", "0.0", "0.0"] for k in range(200)]   # a valid log in which nothing moves
    (folder / "still.csv").write_text("\n".join([",".join(HEADER), *(",".join(r) for r in rows)]) + "\n")
    (folder / "still.json").write_text(json.dumps(META))
    (folder / "existing_file").write_text("keep")
    (folder / "existing_dir").mkdir()
    return folder


def run_cli_fuzz(seed: int, n: int, folder: Path) -> dict[int, int]:
    rng = np.random.default_rng(seed)
    counts: dict[int, int] = {}
    for _ in range(n):
        code = check_cli_case(rng, folder)
        counts[code] = counts.get(code, 0) + 1
        import shutil

        for p in folder.iterdir():   # a successful run's output is fine; clear it for the next case
            if p.name not in ("still.csv", "still.json", "existing_file", "existing_dir"):
                shutil.rmtree(p) if p.is_dir() else p.unlink()
        for p in (folder / "existing_dir").iterdir():   # including what it wrote into the existing folder
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    return counts


def test_mutated_logs_are_read_or_named(tmp_path) -> None:
    counts = run_log_fuzz(seed=20261123, n=300, folder=tmp_path)
    assert counts["error"] > 100 and counts["ok"] > 20, counts


def test_random_command_lines_end_cleanly(tmp_path) -> None:
    counts = run_cli_fuzz(seed=88172645, n=150, folder=cli_folder(tmp_path))
    assert counts.get(2, 0) > 50, counts


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3141, 27182, 16180])
def test_many_mutated_logs(tmp_path, seed) -> None:
    run_log_fuzz(seed=seed, n=3000, folder=tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5772, 14142])
def test_many_command_lines(tmp_path, seed) -> None:
    run_cli_fuzz(seed=seed, n=1000, folder=cli_folder(tmp_path))
