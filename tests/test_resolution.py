"""Resolution protocols (ident.protocols.resolution, ident.protocols.controllers) against the independent event-driven reference
(tests/reference: scipy DOP853 with located events). The reference side re-implements the protocol logic here
(median decisions, the PD loop with its own floor-quantized encoder, the final-rest rule) and shares no code with
ident. Experiments are shortened (N = 20-40) so the file runs in well under a minute."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ident import DriveParams, Plant
from ident.protocols.controllers import ImpulseController, LinearPD
from ident.protocols.resolution import (
    ImpulseResolution,
    LinearResolution,
    ThresholdNotFound,
    find_threshold,
    impulse_experiment,
    impulse_resolution,
    linear_resolution,
)
from tests.reference.event_driven import DriveSI, State, pulse_increments, simulate
from tests.reference.stored import stored

EPS1 = 0.1e-6
WIDTH_S = 1e-3
F_L_STARS = [0.01, 0.1, 1.0]
REL = 1e-6
ABS_FLOOR = 1e-15  # m: for increments that are exactly zero on both sides


def drives(f_l_star: float) -> tuple[DriveParams, DriveSI]:
    return (DriveParams.from_nondim(K_star=1e6, J_l_star=2500, f_l_star=f_l_star),
            DriveSI.from_nondim(K_star=1e6, J_l_star=2500, f_l_star=f_l_star))


def assert_increments_match(got, ref, what: str) -> None:
    got, ref = np.asarray(got), np.asarray(ref)
    assert got.shape == ref.shape, f"{what}: {got.shape} vs {ref.shape}"
    for k, (a, b) in enumerate(zip(got, ref)):
        assert abs(a - b) <= REL * abs(b) + ABS_FLOOR, \
            f"{what}, #{k}: FMU {a * 1e6:.9f} um vs reference {b * 1e6:.9f} um"


def reference_median_decision(incs: list[float], n: int) -> bool | None:
    """The median rule written independently: decided once more than n/2 are on one side of eps1; with all n
    known, the plain median; None while undecided."""
    above = sum(1 for x in incs if x > EPS1)
    below = len(incs) - above
    if 2 * above > n:
        return True
    if 2 * below > n:
        return False
    return bool(np.median(incs) > EPS1) if len(incs) == n else None


# -- impulse protocol vs the reference ----------------------------------------------------------------------
@pytest.mark.parametrize("f_l_star", F_L_STARS)
def test_impulse_protocol_matches_reference(f_l_star: float) -> None:
    n = 30
    params, ref = drives(f_l_star)
    res = impulse_resolution(params, n_pulses=n)
    width_star = WIDTH_S / ref.T_c
    # the whole amplitude sequence of the search: same pulses run, same increments, same decision
    moved = 0
    for amplitude, passed, used in res.median_tests:
        got = impulse_experiment(params, amplitude, used)
        want, _ = pulse_increments(ref, amplitude, width_star, used)
        assert_increments_match(got, want, f"median test at A = {amplitude}")
        assert reference_median_decision(want, n) is passed, f"decision at A = {amplitude}"
        assert used == n or reference_median_decision(want[:-1], n) is None, "the test ran past its decision"
        moved += max(want) > EPS1
    assert moved >= 3  # the comparison covers real motion
    # the final experiment at A_op
    assert res.operating_amplitude == pytest.approx(res.threshold_amplitude * 1.01, rel=1e-15)
    want, _ = pulse_increments(ref, res.operating_amplitude, width_star, n)
    assert_increments_match(res.increments_m, want, f"A_op experiment, f_l* = {f_l_star}")
    assert res.resolution_m == max(res.increments_m) and res.resolution_m > EPS1


@stored
def reference_pd_steps(ref: DriveSI, counts: int, n_steps: int, warmup: int, stop_at_failure: bool) -> list[float]:
    """PD set-point steps on the reference integrator with a floor-quantized encoder (physics.md section 3).

    A step ends at the first sample where both bodies are stuck, the encoder count equals the previous sample's
    and the new output equals the held torque: then nothing can change any more."""
    count_rad = 2.0 * math.pi / 12566
    dt, T_c = 1e-3, ref.T_c
    state = State()
    setpoint = 0
    prev = 0
    held = 0.0
    out = []
    for j in range(warmup + n_steps):
        setpoint += counts
        start = state.q_l
        for _ in range(60_000):
            c = math.floor(state.q_m / count_rad)
            u = 200.0 * (setpoint - c) * count_rad - 19.2 * (c - prev) * count_rad / (dt / T_c)
            u = max(-20.0, min(20.0, u)) * ref.f_m
            settled = state.motor_stuck and state.load_stuck and c == prev and u == held
            prev = c
            if settled:
                break
            state = simulate(ref, state, u, dt)
            held = u
        else:
            raise AssertionError("reference PD step did not settle")
        if j >= warmup:
            out.append((state.q_l - start) * ref.arm_length)
            if stop_at_failure and not out[-1] > EPS1:
                break
    return out


@pytest.mark.parametrize("f_l_star,n_steps,warmup", [(0.01, 20, 6), (0.1, 40, 20), (1.0, 40, 20)])
def test_linear_protocol_matches_reference(f_l_star: float, n_steps: int, warmup: int) -> None:
    params, ref = drives(f_l_star)
    res = linear_resolution(params, n_steps=n_steps, warmup=warmup, max_counts=10)
    # the reference protocol: k = 1, 2, ... until every measured step moves by more than eps1
    for k in range(1, res.counts + 1):
        want = reference_pd_steps(ref, k, n_steps, warmup, stop_at_failure=True)
        consistent = len(want) == n_steps and all(x > EPS1 for x in want)
        assert consistent is (k == res.counts), f"k = {k}"
        assert res.tried[k - 1]["steps_run"] == len(want)
    assert_increments_match(res.increments_m, want, f"PD steps of {res.counts} counts, f_l* = {f_l_star}")
    assert res.resolution_m == max(res.increments_m)


# -- threshold search correctness ---------------------------------------------------------------------------
@pytest.mark.parametrize("f_l_star,n", [(0.1, 41), (1.0, 40)])
def test_threshold_is_first_passing_amplitude(f_l_star: float, n: int) -> None:
    params, _ = drives(f_l_star)
    with Plant(params) as plant:
        a_th, tests = find_threshold(plant, n_pulses=n)
        # full experiments, plain median: A_th passes, A_th - 1e-4 fails
        assert np.median(impulse_experiment(plant, a_th, n)) > EPS1
        assert np.median(impulse_experiment(plant, round(a_th - 1e-4, 12), n)) <= EPS1
        # every early-stopped decision equals the full-experiment median
        for amplitude, passed, used in tests:
            if amplitude > 1.0:  # below: nothing moves at all (|tau*| <= static level)
                assert bool(np.median(impulse_experiment(plant, amplitude, n)) > EPS1) is passed
        # the fine ramp in the last failing coarse interval has no earlier pass
        coarse_fail = max(a for a, ok, _ in tests if not ok and round(a / 0.05, 9).is_integer())
        for i in range(round(coarse_fail / 1e-4), round(a_th / 1e-4)):
            assert not np.median(impulse_experiment(plant, round(i * 1e-4, 12), n)) > EPS1


def test_threshold_not_found_raises() -> None:
    params, _ = drives(0.1)
    with Plant(params) as plant, pytest.raises(ThresholdNotFound, match="no pulse amplitude up to"):
        find_threshold(plant, n_pulses=5, eps1_m=1.0, max_amplitude_star=1.2, coarse_step_star=0.5)


# -- controllers ----------------------------------------------------------------------------------------------
def test_pd_user_loop_and_final_rest_rule() -> None:
    params, _ = drives(0.1)
    with Plant(params) as plant:
        pd_ = LinearPD(params=params)
        pd_.reset(sample=plant.sample())
        incs = [pd_.move(plant, 3) for _ in range(12)]
        s = plant.sample()
        # after a move nothing can change: more samples of the same loop leave the plant and torque unchanged
        torque = plant.torque
        for _ in range(500):
            s2 = plant.step(pd_.control(plant.sample()), pd_.dt_s)
        assert (s2.q_m, s2.q_l, s2.encoder_count) == (s.q_m, s.q_l, s.encoder_count) and plant.torque == torque
        # a user loop with control() reproduces move()
        plant.reset()
        user = LinearPD(params=params)
        user.reset(sample=plant.sample())
        s = plant.sample()
        for _ in range(12):
            user.setpoint_count += 3
            for _ in range(1000):
                s = plant.step(user.control(s), user.dt_s)
    assert sum(incs) > 10 * EPS1
    assert s.arm_position == pytest.approx(sum(incs), rel=1e-9)


def test_impulse_controller_pulse_matches_reference() -> None:
    params, ref = drives(0.1)
    with Plant(params) as plant:
        got = [ImpulseController(2.0).pulse(plant) for _ in range(3)]
    want, _ = pulse_increments(ref, 2.0, WIDTH_S / ref.T_c, 3)
    assert_increments_match(got, want, "ImpulseController.pulse")


# -- results ---------------------------------------------------------------------------------------------------
def test_results_frame_and_plot(tmp_path) -> None:
    params, _ = drives(0.1)
    imp = impulse_resolution(params, n_pulses=20)
    lin = linear_resolution(params, n_steps=20, warmup=20)
    assert isinstance(imp, ImpulseResolution) and isinstance(lin, LinearResolution)
    for res in (imp, lin):
        frame = res.to_frame()
        assert isinstance(frame, pd.DataFrame) and len(frame) == 20
        assert frame["increment_m"].max() == res.resolution_m
        assert res.min_m <= res.median_m <= res.resolution_m and res.std_m >= 0
        png = res.plot(tmp_path / f"{type(res).__name__}.png")
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- bad input -------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("call,match", [
    (lambda: impulse_experiment(None, 1.5, 0), "n_pulses"),
    (lambda: impulse_experiment(None, 1.5, 2.5), "n_pulses"),
    (lambda: impulse_experiment(None, float("nan"), 3), "amplitude_star"),
    (lambda: impulse_experiment(None, 1.5, 3, width_s=0.0), "width_s"),
    (lambda: impulse_experiment("nominal", 1.5, 3), "DriveParams or a Plant"),
    (lambda: impulse_resolution(None, n_pulses=0), "n_pulses"),
    (lambda: impulse_resolution(None, n_pulses=10, eps1_m=0.0), "eps1_m"),
    (lambda: impulse_resolution(None, n_pulses=10, eps1_m=-1e-7), "eps1_m"),
    (lambda: impulse_resolution(None, n_pulses=10, eps2=0.0), "eps2"),
    (lambda: impulse_resolution(None, n_pulses=10, tol_star=-1e-4), "tol_star"),
    (lambda: impulse_resolution(None, n_pulses=10, fmi_version=4), "fmi_version"),
    (lambda: linear_resolution(None, n_steps=0), "n_steps"),
    (lambda: linear_resolution(None, n_steps=10, warmup=-1), "warmup"),
    (lambda: linear_resolution(None, n_steps=10, eps1_m=0.0), "eps1_m"),
    (lambda: linear_resolution(None, n_steps=10, max_counts=0), "max_counts"),
    (lambda: ImpulseController(1.5, width_s=-1e-3), "width_s"),
    (lambda: LinearPD(rate_hz=0.0), "rate_hz"),
    (lambda: LinearPD(Kp_star=float("inf")), "Kp_star"),
    (lambda: LinearPD().control(None), "reset"),
])
def test_bad_input_raises_value_error(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
