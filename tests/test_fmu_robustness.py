"""The FMU under calls a demanding FMI user makes (issue 17): degenerate steps, damaged FMU states, non-finite start
times, status getters, the error state, log categories and the modelDescription's generation data.

The FMU's C functions are called directly (``tests/fmi_harness.Api``), for FMI 2.0 and 3.0 alike. Work is asserted
through the FMU's own count of model evaluations (log category ``logSteps``), never through a clock.
"""
from __future__ import annotations

import math
import re
import struct
import zipfile
from pathlib import Path

import pytest

from fmu_build import build_fmu
from fmu_build import variables as V
from fmu_build.build import package_version
from tests.fmi_harness import DISCARD, ERROR, OK, Api

VR = {v.name: v.vr for v in V.VARIABLES}
BUDGET = int(re.search(r"#define HD_WORK_BUDGET (\d+)", (Path(V.__file__).parent / "c" / "model.h").read_text())[1])


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def api(request, tmp_path: Path) -> Api:
    return Api(build_fmu(fmi_version=request.param), request.param, tmp_path)


def started(api: Api, logging: bool = True, start: float = 0.0, **values: float) -> int:
    """A new instance with ``values`` set (SI, by variable name), initialized at ``start``."""
    c = api.instantiate(logging)
    assert c
    for name, value in values.items():
        assert api.reals(c, [VR[name]], [value])[0] == OK, api.log
    assert all(s == OK for s in api.enter_init(c, start) if s is not None), api.log
    assert api.simple(c, "ExitInitializationMode") == OK, api.log
    return c


def step_report(api: Api, c: int, t: float, h: float) -> tuple[int, int, int, str]:
    """doStep with the logSteps report on: (status, switching events, model evaluations, last message)."""
    api.debug_logging(c, True, [])
    api.log.clear()
    status = api.do_step(c, t, h)
    msg = api.log[-1][2] if api.log else ""
    m = re.search(r"(\d+) switching events, (\d+) model evaluations", msg)
    return status, int(m[1]) if m else -1, int(m[2]) if m else -1, msg


def suggested_step(msg: str) -> float:
    return float(re.search(r"use communication steps of at most ([0-9.e+-]+) s", msg)[1])


def follow_suggestions(api: Api, values: dict, msg: str, tries: int = 4) -> tuple[int, str]:
    """Retry the first step with the step size each refusal names (a hint: the first part of a step may be cheaper
    than the rest): it must lead to a step that is taken within a few tries."""
    for _ in range(tries):
        c = started(api, **values)
        status, _, work, msg = step_report(api, c, 0.0, suggested_step(msg))
        if status == OK:
            assert work <= BUDGET, msg
            return work, msg
    raise AssertionError(f"still refused after {tries} suggested steps: {msg}")


# ------------------------------------------------------------------------------------------ degenerate steps --

def test_subnormal_step_after_a_breakaway_is_one_event(api: Api) -> None:
    """Effect on, a body slipping at v = 0 (it just broke away), a 4.9e-324 s step: every event advances time, so
    this is one event (it was the same event two million times, 495 s)."""
    c = started(api, b_m=1e-4)
    assert api.reals(c, [VR["motor_torque"]], [0.03])[0] == OK
    status, events, work, msg = step_report(api, c, 0.0, 5e-324)
    assert status == OK and events <= 1 and 0 < work <= 1000, msg
    status, events, work, msg = step_report(api, c, 5e-324, 1e-3)  # and the drive moves on normally
    assert status == OK and work <= BUDGET, msg


def test_endless_stick_slip_in_a_huge_step_is_refused_within_the_budget(api: Api) -> None:
    """Base model, Coulomb ringing that needs billions of events to decay, one step of 1e20 s: refused once the
    budget is spent (it used to take 2,000,000 events, 8-30 s), naming a step size that works."""
    values = dict(f_m=1e6, f_l=1e-9, q_l_start=1e-3)
    c = started(api, **values)
    status, _, _, msg = step_report(api, c, 0.0, 1e20)
    assert status == ERROR and f"more than the {BUDGET} model evaluations" in msg, msg
    follow_suggestions(api, values, msg)


@pytest.mark.parametrize("hardening,q_l_start", [(1e10, -1e-2), (1e12, -1e-1)])
def test_stiff_effects_refuse_a_step_they_cannot_afford(api: Api, hardening: float, q_l_start: float) -> None:
    """Stribeck + hardening + a large initial deflection: a 1 ms step needed up to 82 s; now refused within the
    budget (or before any work when the substeps alone exceed it) with a step size that works."""
    values = dict(stribeck_ratio=0.5, stribeck_velocity=5e-4, hardening=hardening, q_l_start=q_l_start)
    c = started(api, **values)
    status, _, _, msg = step_report(api, c, 0.0, 1e-3)
    assert status == ERROR and "model evaluations one doStep may do" in msg, msg
    follow_suggestions(api, values, msg)


@pytest.mark.parametrize("start,h", [(1.0, -1e-3), (1.0, math.nan), (1.0, math.inf), (1e308, 1e308)])
def test_steps_that_cannot_be_taken_are_errors(api: Api, start: float, h: float) -> None:
    c = started(api, start=start)
    status, _, _, msg = step_report(api, c, start, h)
    assert status == ERROR and ("step size" in msg or "largest double" in msg), msg


# ------------------------------------------------------------------------------------------ FMU states --------

def layout() -> dict[str, tuple[int, str]]:
    """Byte offset and struct format of each serialized field (the order of ``snapshot_fields`` in model.c)."""
    fields = [(v.name, "d") for v in V.PARAMETERS if v.type == "Real"]
    fields += [(v.name, "d") for v in V.INPUTS]
    fields += [(v.name, "i") for v in V.PARAMETERS if v.type == "Integer"]
    fields += [(v.name, "d") for v in V.OUTPUTS if v.type == "Real"]
    fields += [(v.name, "i") for v in V.OUTPUTS if v.type == "Integer"]
    fields += [(v.name, "i") for v in V.OUTPUTS if v.type == "Boolean"]
    fields += [("time", "d"), ("motor_dir", "i"), ("load_dir", "i"), ("hyst_dir", "i"), ("hyst_d0", "d"),
               ("hyst_z0", "d"), ("event_count", "q"), ("model_evaluations", "d"), ("phase", "i"),
               ("start_time", "d")]
    out, offset = {}, 16
    for name, fmt in fields:
        out[name] = (offset, fmt)
        offset += struct.calcsize(fmt)
    out["<end>"] = (offset, "")
    return out


def serialized(api: Api, c: int) -> bytes:
    status, h = api.get_state(c)
    assert status == OK
    status, data = api.serialize(c, h)
    api.free_state(c, h)
    assert status == OK
    return data


def test_serialized_state_has_no_padding_and_is_a_function_of_the_state(api: Api) -> None:
    """Every byte is a field (the FMI 3 state used to carry 4 uninitialised padding bytes): the size is the sum of
    the fields, and two instances in the same state serialize to the same bytes."""
    states = []
    for _ in range(2):
        c = started(api, q_l_start=-2e-5)
        assert api.reals(c, [VR["motor_torque"]], [0.0095])[0] == OK
        assert api.do_step(c, 0.0, 0.01) == OK
        states.append(serialized(api, c))
    assert len(states[0]) == layout()["<end>"][0]
    assert states[0] == states[1]


@pytest.mark.parametrize("field,value,named", [
    ("K_s", 1e300, "K_s"), ("J_l", -1.0, "J_l"), ("J_l", math.inf, "J_l"), ("motor_torque", math.nan, "motor_torque"),
    ("phase", 4098, "phase"), ("q_m", math.nan, "q_m"), ("motor_stuck", 7, "motor_stuck"),
    ("hyst_dir", 0, "hysteresis branch"), ("v_l", 0.5, "stuck body moves"), ("start_time", math.inf, "start_time"),
    ("encoder_counts_per_rev", 0, "encoder_counts_per_rev"), ("hyst_z0", 1.0, "hysteresis anchor")])
def test_deserialized_state_is_validated_like_parameters(api: Api, field: str, value: float, named: str) -> None:
    """A state whose fields were altered is refused with a message naming the field (it used to be taken: K_s =
    1e300 hung steps, J_l = -1 gave NaN, a phase of 4098 tripped UBSan); the instance then needs a reset."""
    c = started(api)  # at rest: both bodies stuck, so a velocity makes a "stuck body moves"
    data = bytearray(serialized(api, c))
    offset, fmt = layout()[field]
    struct.pack_into(fmt, data, offset, value)
    status, h = api.deserialize(c, bytes(data))
    assert status == ERROR and named in api.log[-1][2], api.log
    assert api.do_step(c, 0.0, 1e-3) == ERROR  # the error state
    assert api.simple(c, "Reset") == OK


def test_truncated_or_foreign_state_is_refused(api: Api) -> None:
    c = started(api)
    data = serialized(api, c)
    for bad, why in ((data[:-1], "wrong size"), (data + b"\0", "wrong size"), (b"", "wrong size"),
                     (b"XXXX" + data[4:], "does not come from this FMU")):
        assert api.simple(c, "Reset") == OK
        status, _ = api.deserialize(c, bad)
        assert status == ERROR and why in api.log[-1][2], api.log


# ------------------------------------------------------------------------------------------ calls and states --

@pytest.mark.parametrize("start", [math.nan, math.inf, -math.inf])
def test_non_finite_start_time_is_refused(api: Api, start: float) -> None:
    c = api.instantiate(True)
    statuses = api.enter_init(c, start)
    assert statuses[0] == ERROR and "startTime" in api.log[-1][2], api.log
    assert api.simple(c, "ExitInitializationMode") == ERROR  # the error state
    assert api.simple(c, "Reset") == OK
    assert all(s == OK for s in api.enter_init(c, 0.0) if s is not None)


def test_error_state_allows_only_what_the_standard_allows(api: Api) -> None:
    """After Error: no step, no set, no terminate; getters, debug logging and the FMU state functions work, and a
    state saved before the error resumes the simulation (FMI 2 "error"; FMI 3: Terminated after an error)."""
    c = started(api, q_l_start=-2e-5)
    status, saved = api.get_state(c)
    assert status == OK
    assert api.do_step(c, 0.0, -1.0) == ERROR
    assert api.do_step(c, 0.0, 1e-3) == ERROR and "must not be called" in api.log[-1][2]
    assert api.reals(c, [VR["motor_torque"]], [0.0])[0] == ERROR
    assert api.simple(c, "Terminate") == ERROR
    assert api.reals(c, [VR["q_l"]])[0] == OK
    assert api.debug_logging(c, True, ["logStatusError"]) == OK
    status, h = api.get_state(c)
    assert status == OK and api.serialize(c, h)[0] == OK and api.free_state(c, h) == OK
    assert api.set_state(c, saved) == OK  # saved while stepping: stepping again
    assert api.do_step(c, 0.0, 1e-3) == OK
    assert api.free_state(c, saved) == OK


def test_out_of_range_values_are_discarded_and_the_simulation_continues(api: Api) -> None:
    c = started(api)
    assert api.reals(c, [VR["motor_torque"]], [math.nan])[0] == DISCARD
    assert "motor_torque" in api.log[-1][2]
    assert api.do_step(c, 0.0, 1e-3) == OK


def test_fmi2_status_getters_answer_what_they_can_and_discard_the_rest(tmp_path: Path) -> None:
    """FMI 2.0: "If a status is required which cannot be retrieved by the slave it returns fmi2Discard". The FMU
    never returns fmi2Pending, so only fmi2LastSuccessfulTime and fmi2Terminated have answers."""
    api = Api(build_fmu(fmi_version=2), 2, tmp_path)
    c = api.instantiate(True)
    assert api.status_getter(c, "RealStatus", 2) == ERROR  # not before initialization: the error state
    c = started(api, start=2.0)
    DO_STEP, PENDING, LAST_TIME, TERMINATED = range(4)
    for kind, which, expected in [("Status", DO_STEP, DISCARD), ("StringStatus", PENDING, DISCARD),
                                  ("RealStatus", LAST_TIME, OK), ("BooleanStatus", TERMINATED, OK),
                                  ("IntegerStatus", DO_STEP, DISCARD), ("RealStatus", DO_STEP, DISCARD)]:
        assert api.status_getter(c, kind, which) == expected, (kind, which, api.log)
    assert api.do_step(c, 2.0, 1e-3) == OK  # Discard left the instance usable


# ------------------------------------------------------------------------------------------ logging -----------

def test_model_descriptions_carry_log_categories_and_generation_data(fmu_any: Path) -> None:
    with zipfile.ZipFile(fmu_any) as zf:
        xml = zf.read("modelDescription.xml").decode()
    names = re.findall(r'<Category name="([^"]+)"', xml)
    assert names == [c.name for c in V.LOG_CATEGORIES]
    assert re.search(r'generationDateAndTime="\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ"', xml)
    assert f'version="{package_version()}"' in xml and f'author="{V.AUTHOR}"' in xml


def test_debug_logging_honours_categories(api: Api) -> None:
    c = started(api)  # loggingOn: the default categories (Error and Discard), no step reports
    api.log.clear()
    assert api.do_step(c, 0.0, 1e-3) == OK and not api.log
    assert api.debug_logging(c, True, ["logSteps"]) == OK  # only step reports now
    api.log.clear()
    assert api.do_step(c, 1e-3, 1e-3) == OK and [cat for _, cat, _ in api.log] == ["logSteps"]
    api.log.clear()
    assert api.reals(c, [VR["motor_torque"]], [math.inf])[0] == DISCARD and not api.log
    assert api.debug_logging(c, False, []) == OK  # all off
    api.log.clear()
    assert api.do_step(c, 2e-3, -1.0) == ERROR and not api.log
    assert api.debug_logging(c, True, ["noSuchCategory"]) == ERROR
    assert api.simple(c, "Reset") == OK and api.debug_logging(c, True, []) == OK
    api.log.clear()
    assert api.debug_logging(c, True, ["noSuchCategory"]) == ERROR
    assert "logStatusError, logStatusDiscard, logSteps" in api.log[-1][2]


def test_logging_off_at_instantiation(api: Api) -> None:
    """loggingOn = false: FMI 3 logs nothing ("any logging is disabled"); FMI 2 still reports errors (its logger
    "was called" for fmi2Error) but not Discard."""
    c = started(api, logging=False)
    api.log.clear()
    assert api.reals(c, [VR["motor_torque"]], [math.nan])[0] == DISCARD and not api.log
    assert api.do_step(c, 0.0, -1.0) == ERROR
    assert bool(api.log) == (api.fmi == 2)
