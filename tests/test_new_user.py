"""What a new user meets first (issue 18): a report whose sentences follow its numbers on any drive, the start-up
transient rule, the CLI's help texts, one unit convention for every command's JSON, and one torque time-stamp
convention shared by ``hdrive demo``, ``write_log`` and ``read_log``."""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ident import DriveParams
from ident.cli import build_parser, main
from ident.common.units import non_si_keys, plain_json, si_keys
from ident.fitting.logs import read_log
from ident.model.plant import Plant
from ident.protocols.transient import start_up_transient
from ident.studies.paper import write_study

SECOND_DRIVE = {"K_s": 3e4, "f_l_star": 0.5}


# -- the report's sentences follow its numbers ---------------------------------------------------------------------
N_PULSES = 120   # small, yet enough for the second drive's transient to settle while the nominal one's does not


@pytest.fixture(scope="module")
def studies(tmp_path_factory) -> dict[str, tuple[object, Path, str]]:
    """The study on the nominal drive and on a second one, with a small protocol."""
    out = {}
    for name, params in (("nominal", DriveParams()), ("second", DriveParams().with_values(**SECOND_DRIVE))):
        folder = tmp_path_factory.mktemp(name) / "study"
        study, report = write_study(folder, params, n_pulses=N_PULSES, n_steps=30, levels=5, workers=0)
        out[name] = (study, folder, report.read_text())
    return out


@pytest.fixture(params=["nominal", "second"])
def study_out(request, studies) -> tuple[object, Path, str]:
    return studies[request.param]


def settled_end(x: np.ndarray) -> tuple[int, bool]:
    """The documented transient rule, written again here (no product code): the last quarter's range; the
    transient's size is the largest distance outside it (none if not above the range's width); the band is the range
    widened by 2 % of that size; the end is the last pulse outside; settled when that end is in the first half."""
    ref = x[(3 * len(x)) // 4:]
    size = max(max(ref.min() - v, v - ref.max()) for v in x)
    if size <= ref.max() - ref.min():
        return 0, True
    tol = 0.02 * size
    outside = [i for i, v in enumerate(x) if v < ref.min() - tol or v > ref.max() + tol]
    end = outside[-1] + 1
    return end, end <= len(x) // 2


def one_of(text: str, holds: bool, yes: str, no: str) -> None:
    """Exactly the sentence that matches the verdict is in the report."""
    assert (yes in text, no in text) == (holds, not holds), (holds, yes, no)


def test_growth_sentence_follows_the_sweep_table(study_out) -> None:
    _, out, text = study_out
    df = pd.read_csv(out / "sweep.csv").sort_values("f_l_star")
    x, y = df["f_l_star"].to_numpy(), df["resolution_um"].to_numpy()
    slope, intercept = np.polyfit(x, y, 1)
    r2 = 1 - np.sum((y - slope * x - intercept) ** 2) / np.sum((y - y.mean()) ** 2)
    holds = slope > 0 and r2 >= 0.9 and y[-1] / y[0] >= 2
    one_of(text, holds, "the base model reproduces the paper's linear growth",
           "the base model does not reproduce the paper's linear growth")
    one_of(text, holds, 'which agrees with the paper\'s "grows linearly"',
           'which differs from the paper\'s "grows linearly"')  # the findings bullet
    spread = df["threshold_amplitude"].max() / df["threshold_amplitude"].min() - 1
    one_of(text, spread < 0.01, "the threshold hardly depends on f_l*", "the threshold depends on f_l* on this drive")
    change = df["median_um"].iloc[-1] / df["median_um"].iloc[0] - 1
    one_of(text, abs(change) <= 0.02, "load friction leaves the median where the motor puts it",
           "the median itself changes with f_l*")


def test_figures_and_verdicts_follow_the_increment_tables(study_out) -> None:
    study, out, text = study_out
    imp = pd.read_csv(out / "impulse_increments.csv")["increment_um"].to_numpy()
    lin = pd.read_csv(out / "linear_increments.csv")
    counts, lin_max = int(lin["counts"].iloc[0]), lin["increment_um"].max()
    one_of(text, abs(imp.max() - 0.30) < 0.005, f"{imp.max():.3f} µm, which agrees",
           f"{imp.max():.3f} µm, which differs")
    one_of(text, counts == 2 and abs(lin_max - 3) < 0.5, "as in the paper (two counts, 3 µm)",
           "where the paper reports two counts, 3 µm")
    ratio = lin_max / imp.max()
    one_of(text, ratio > 10, f"{ratio:.1f}x, which agrees", f"{ratio:.1f}x, which differs")
    hi = study.sweep.results[-1].increments_m
    first = hi[np.flatnonzero(hi)[0]]
    one_of(text, first > 2 * np.median(hi), "this is the paper's avalanche", "this is not the paper's avalanche")
    cmp = study.comparison().set_index("claim")["verdict"]
    assert cmp["impulse resolution"] == ("agrees" if abs(imp.max() - 0.30) < 0.005 else "differs")


def test_transient_sentence_follows_the_increments(study_out) -> None:
    _, out, text = study_out
    x = pd.read_csv(out / "impulse_increments.csv")["increment_um"].to_numpy()
    end, settled = settled_end(x)
    if not settled:
        assert f"has not settled within its N = {len(x)} pulses (pulse {end} is still outside" in text
        assert "I can't tell its steady-state max" in text and "After the transient the max" not in text
        return
    assert f"The transient ends after pulse {end}." in text
    max_pulse = int(np.argmax(x)) + 1
    if max_pulse <= end:
        assert f"pulse {max_pulse} of a start-up transient that ends after pulse {end}" in text
        assert f"After the transient the max is **{x[end:].max():.4f} µm**" in text
    else:
        assert "so it is also the steady-state max" in text


def test_the_two_drives_reach_different_conclusions(studies) -> None:
    """The prose is not fixed text: with the same small protocol, the nominal drive and the second one get different
    sentences (each report is checked against its own tables by the tests above)."""
    alternatives = ["the threshold hardly depends on f_l*", "the median itself changes with f_l*",
                    "I can't tell its steady-state max", "the spring barely acts on the motor",
                    "this is the paper's avalanche", "the base model reproduces the paper's linear growth"]
    said = {name: tuple(a in text for a in alternatives) for name, (_, _, text) in studies.items()}
    assert said["nominal"] != said["second"], said


# -- the transient rule ---------------------------------------------------------------------------------------------
def test_transient_of_a_decaying_alternation() -> None:
    n = 400
    k = np.arange(n)
    x = 1.0 + 0.2 * (-1.0) ** k * 0.9**k       # size 0.2; settled once 0.2 * 0.9^k <= 2 % of 0.2, i.e. k >= 38
    t = start_up_transient(x)
    assert t.settled and t.end_pulse == 38 and t.max_pulse == 1 and t.max_in_transient
    assert t.steady_max_m == pytest.approx(x[38:].max()) and t.steady_max_m < x.max()


def test_transient_not_settled_and_too_short() -> None:
    x = np.linspace(1.0, 2.0, 100)              # still drifting: the last half keeps leaving the band
    t = start_up_transient(x)
    assert t.settled is False and t.steady_max_m is None and not t.max_in_transient
    assert start_up_transient(np.ones(5)).settled is None
    flat = start_up_transient(np.full(50, 3.0))
    assert flat.settled and flat.end_pulse == 0 and flat.steady_max_m == 3.0
    jitter = 3.0 + 1e-15 * np.random.default_rng(1).standard_normal(200)   # rounding-level scatter: no transient
    assert start_up_transient(jitter).end_pulse == 0


# -- JSON unit convention -------------------------------------------------------------------------------------------
def test_si_keys_renames_and_scales() -> None:
    d = {"impulse_resolution_um": {"value": 0.12, "ci95": [0.1, 0.14]}, "elapsed_s": 3.0, "J_m": 2e-5,
         "steps": [{"predicted_resolution_um": 0.5, "delay_ms": 2}], "increment_um": 1.0, "increment_m": 1e-6,
         "counts": 2, "ok": True, "nan_um": float("nan")}
    out = si_keys(d)
    assert out["impulse_resolution_m"]["value"] == pytest.approx(0.12e-6)
    assert out["impulse_resolution_m"]["ci95"] == pytest.approx([0.1e-6, 0.14e-6])
    assert out["steps"][0] == pytest.approx({"predicted_resolution_m": 0.5e-6, "delay_s": 2e-3})
    assert out["increment_m"] == 1e-6 and "increment_um" not in out
    assert (out["elapsed_s"], out["J_m"], out["counts"], out["ok"]) == (3.0, 2e-5, 2, True)
    assert non_si_keys(d) == ["impulse_resolution_um", "steps[0].predicted_resolution_um", "steps[0].delay_ms",
                              "increment_um", "nan_um"]
    assert non_si_keys(out) == [] and plain_json(out)["nan_m"] is None
    json.dumps(plain_json(out), allow_nan=False)


def json_of(argv: list[str], capsys) -> dict:
    assert main(argv) == 0, capsys.readouterr().err
    captured = capsys.readouterr()
    return json.loads(captured.out)


def test_every_command_prints_si_json(tmp_path, capsys) -> None:
    """Each cheap command's --json document has no key in scaled units (µm, ms, ...) and is strict JSON. identify,
    predict, diagnose and paper-effects pass through the same ``main`` (their JSON is checked in their own tests)."""
    runs = {
        "build-fmu": ["build-fmu", "--out", str(tmp_path / "fmu"), "--json"],
        "demo": ["demo", "--out", str(tmp_path / "demo"), "--pulses", "2", "--json"],
        "resolution": ["resolution", "--controller", "impulse", "--pulses", "20", "--increments", "--json"],
        "sweep": ["sweep", "--levels", "3", "--pulses", "20", "--workers", "0", "--out", str(tmp_path / "s"), "--json"],
        "study": ["study", "--levels", "3", "--pulses", "20", "--steps", "10", "--workers", "0", "--out",
                  str(tmp_path / "st"), "--json"],
    }
    docs = {name: json_of(argv, capsys) for name, argv in runs.items()}
    for name, d in docs.items():
        assert non_si_keys(d) == [], name
        json.dumps(d, allow_nan=False)
    assert len(docs["demo"]["increments_m"]) == 2 and len(docs["resolution"]["increments_m"]) == 20
    assert docs["study"]["impulse"]["resolution_m"] > 0 and "slope_m" in docs["study"]["trend"]


# -- help texts -----------------------------------------------------------------------------------------------------
RST = re.compile(r"``|:(func|class|meth|mod|attr|ref):|\*\*|^\s*\.\. ", re.M)


def subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_every_option_has_plain_help() -> None:
    parser = build_parser()
    assert not RST.search(parser.format_help())
    for name, sub in subparsers(parser).items():
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            assert action.help and action.help != argparse.SUPPRESS, f"{name} {action.option_strings}: no help"
        text = sub.format_help()
        assert not RST.search(text), f"{name}: markup in --help: {RST.search(text).group(0)!r}"
        assert not re.search(r"(?<![-\w])um\b", text), f"{name}: 'um' in --help (use µm)"
    subs = subparsers(parser)
    scheduler = next(a for a in subs["predict"]._actions if "--scheduler" in a.option_strings)
    assert "draws" in scheduler.help and "levels" not in scheduler.help
    controller = next(a for a in subs["resolution"]._actions if "--controller" in a.option_strings)
    assert "impulse" in controller.help and "linear" in controller.help


# -- torque time stamps ---------------------------------------------------------------------------------------------
def test_demo_log_follows_the_torque_convention(tmp_path, capsys) -> None:
    """demo's CSV is a log: read_log reads it, and holding motor_torque_Nm[k] over [t_k, t_k+1) from rest reproduces
    its positions exactly; stamping each torque at the end of its step (the old demo) does not."""
    d = json_of(["demo", "--out", str(tmp_path), "--pulses", "3", "--json"], capsys)
    log = read_log(d["csv"])
    assert log.n > 100 and log.meta.sample_rate_hz == 1000.0 and d["meta"].endswith("pulse_train.json")
    with Plant(DriveParams()) as plant:
        q_m, q_l = plant.positions(log.motor_torque_Nm[:-1], log.dt)
        np.testing.assert_array_equal(q_m, log.motor_pos_rad)
        np.testing.assert_array_equal(q_l, log.load_pos_rad)
        late_m, _ = plant.positions(log.motor_torque_Nm[1:], log.dt)   # torque stamped at the end of its step
    assert np.max(np.abs(late_m - log.motor_pos_rad)) > 1e-4
    assert log.motor_torque_Nm[0] > 0 and log.motor_torque_Nm[-1] == 0.0   # the first pulse starts at t = 0
    df = pd.read_csv(d["csv"])
    increments = [float(x) for x in d["increments_m"]]
    assert sum(increments) == pytest.approx(df["arm_position_m"].iloc[-1], rel=1e-9)
