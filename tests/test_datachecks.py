"""Data before physics (issue 21, item 5): each mistake a user makes with a log is named as such -- before anything
is fitted -- on a log from the independent reference generator with that mistake put in."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ident import read_log
from ident.fitting.datachecks import DataCheckError, check_log
from ident.fitting.identify import identify
from ident.fitting.logs import LogError
from tests.ident_support import read_back
from tests.reference.generator import identification_case
from tests.reference.generator.logs import IDENTIFICATION_KINDS


@pytest.fixture(scope="module")
def moves(tmp_path_factory):
    """A clean 2 s log with long moves (the generator's diagnosis-style mix: slow trapezoidal moves of up to a few
    motor revolutions and pulses), written in the product's format: (csv path, its sidecar dict, the log)."""
    folder = tmp_path_factory.mktemp("checks")
    g = identification_case(4301, "mix", duration_s=2.0)
    csv, sidecar = g.write(folder, "clean")
    return csv, json.loads(sidecar.read_text()), read_log(csv)


def _status(checks: list[dict]) -> dict[str, str]:
    return {c["check"]: c["status"] for c in checks}


def test_a_clean_log_passes_every_check(moves) -> None:
    _, _, log = moves
    checks = check_log(log)
    assert _status(checks) == {"sample_rate": "ok", "encoder_quantization": "ok", "gear_ratio": "ok",
                               "load_sensor": "ok", "torque": "ok"}, checks
    ratio = next(c for c in checks if c["check"] == "gear_ratio")
    assert ratio["ratio_over_r"] == pytest.approx(1.0, abs=0.01)


@pytest.mark.parametrize("off", [0.008, 2e-4])
def test_sample_rate_off_the_time_column_is_an_error_naming_both(moves, tmp_path, off) -> None:
    csv, sidecar, _ = moves
    meta = {**sidecar, "sample_rate_hz": sidecar["sample_rate_hz"] * (1 + off)}
    with pytest.raises(LogError) as info:
        read_log(csv, meta)
    msg = str(info.value)
    assert f"sample_rate_hz = {meta['sample_rate_hz']:.10g} Hz" in msg
    assert f"runs at {sidecar['sample_rate_hz']:.10g} Hz" in msg


@pytest.mark.parametrize("factor", [2.0, 0.5])
def test_a_wrong_gear_ratio_is_named_before_fitting(moves, factor) -> None:
    csv, sidecar, _ = moves
    log = read_log(csv, {**sidecar, "r": sidecar["r"] * factor})
    with pytest.raises(DataCheckError) as info:
        identify(log)
    msg = str(info.value)
    assert "gear ratio is inconsistent" in msg and f"r = {sidecar['r'] * factor:.6g}" in msg
    assert f"{1 / factor:.4g} x the sidecar's r" in msg.replace("1.000 x", "1 x")
    assert _status(info.value.checks)["gear_ratio"] == "error"


@pytest.mark.parametrize("scale, words", [(180 / math.pi, "in degrees"), (-1.0, "with the wrong sign"),
                                          (1e6, "in microradians")])
def test_a_load_sensor_in_the_wrong_unit_or_sign_is_named(moves, scale, words) -> None:
    csv, _, _ = moves
    log = read_log(csv)
    log.load_pos_rad = log.load_pos_rad * scale
    with pytest.raises(DataCheckError) as info:
        identify(log)
    assert f"column load_pos_rad looks {words}" in str(info.value)
    assert _status(info.value.checks)["load_sensor"] == "error"


def test_an_encoder_off_its_counts_is_named(moves) -> None:
    csv, sidecar, _ = moves
    wrong = read_log(csv, {**sidecar, "encoder_counts_per_rev": sidecar["encoder_counts_per_rev"] + 7})
    checks = check_log(wrong)
    assert _status(checks)["encoder_quantization"] == "error"
    with pytest.raises(DataCheckError, match=r"column motor_pos_rad, row \d+: the encoder is .* counts from the "
                                             r"first sample .* not a whole number"):
        identify(wrong)
    log = read_log(csv)
    log.motor_pos_rad = log.motor_pos_rad * (180 / math.pi)   # the encoder column in degrees
    assert _status(check_log(log))["encoder_quantization"] == "error"


def test_an_encoder_declared_finer_than_it_counts_is_a_warning(moves) -> None:
    csv, sidecar, _ = moves
    log = read_log(csv, {**sidecar, "encoder_counts_per_rev": sidecar["encoder_counts_per_rev"] * 4})
    check = next(c for c in check_log(log) if c["check"] == "encoder_quantization")
    assert check["status"] == "warning" and check["multiple"] == 4


def test_too_little_travel_is_skipped_not_guessed() -> None:
    """A log whose motor hardly moves cannot tell the gear ratio: the check says so instead of failing."""
    log = read_back(identification_case(4302, "pulse_train", duration_s=0.5))
    checks = {c["check"]: c for c in check_log(log)}
    assert checks["gear_ratio"]["status"] in ("ok", "skipped")
    assert checks["sample_rate"]["status"] == "ok"
    assert np.isfinite(checks["sample_rate"]["relative_difference"])


#: one log per excitation the identifier accepts, each of its own random drive (seeds in no other suite), 1.5 s
TORQUE_LOGS = [(4481 + i, kind) for i, kind in enumerate(IDENTIFICATION_KINDS)]
#: the mistakes the torque check is for: (the factor on the torque column, the factor on f_m_Nm, the error's words)
TORQUE_MISTAKES = {"the torque's sign flipped": (-1.0, 1.0, "looks flipped"),
                   "the torque in mN.m": (1e3, 1.0, "reads too large"),
                   "the torque in kN.m": (1e-3, 1.0, "reads too small by about"),
                   "f_m_Nm 1000x too large": (1.0, 1e3, "reads too small by about")}


@pytest.fixture(scope="module")
def torque_logs() -> dict[tuple[int, str], object]:
    return {case: read_back(identification_case(case[0], case[1], duration_s=1.5)) for case in TORQUE_LOGS}


def test_the_torques_work_passes_every_excitation_and_catches_each_unit_and_sign_mistake(torque_logs) -> None:
    """The torque check (``datachecks.check_torque``) on the independent generator's logs of six drives, one per
    excitation: never an error on the log as recorded (its torque does 1-1.3x the motor's Coulomb work), and an
    error naming motor_torque_Nm for each mistake wherever the recorded log was decided. Where the torque changes
    often against a short motor travel (the pulse train, the reversals, the PD steps, the chirp: a total variation
    of 40-600 f_m against 0-0.2 rad of travel in 1.5 s) the encoder's quantization could move the work by more than
    a quarter of the Coulomb work, and the check says it cannot tell rather than guess; it decides the torque steps
    and the default design."""
    from dataclasses import replace

    from ident.fitting.datachecks import check_torque

    decided = set()
    for case, log in torque_logs.items():
        check = check_torque(log)
        assert check["status"] in ("ok", "skipped"), (case, check)
        if check["status"] == "skipped":
            continue
        decided.add(case[1])
        assert 1.0 - check["work_error"] <= check["work_over_coulomb"] <= check["most_dissipation"], (case, check)
        for what, (torque, f_m, words) in TORQUE_MISTAKES.items():
            wrong = replace(log, motor_torque_Nm=log.motor_torque_Nm * torque,
                            meta=replace(log.meta, f_m_Nm=log.meta.f_m_Nm * f_m))
            bad = check_torque(wrong)
            assert bad["status"] == "error" and "column motor_torque_Nm" in bad["detail"], (case, what, bad)
            assert words in bad["detail"], (case, what, bad["detail"])
    assert {"default", "steps"} <= decided, decided


def test_a_torque_in_the_wrong_unit_stops_identify_and_diagnose_before_fitting(moves) -> None:
    """The torque check is one of the identifier's data checks: ``identify`` and ``diagnose`` raise it before any
    fit (before: a torque in mN.m ran a 150 s diagnosis to 2.4e8x the noise and called the misfit unexplained)."""
    from ident.diagnosis.engine import diagnose

    csv, _, _ = moves
    log = read_log(csv)
    log.motor_torque_Nm = log.motor_torque_Nm * 1e3
    for run in (identify, lambda x: diagnose(x, workers=0)):
        with pytest.raises(DataCheckError) as info:
            run(log)
        assert "column motor_torque_Nm" in str(info.value) and _status(info.value.checks)["torque"] == "error"
