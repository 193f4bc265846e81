"""Self-tests of the independent reference integrator (tests/reference/event_driven.py) against analytic truths.

The reference is the yardstick for the C FMU, so it is checked here without any FMU: rigid-body limit, free
ringing, Coulomb-damped ringing, energy balance and the absence of creep at rest.
"""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from tests.reference.event_driven import DriveSI, State, pulse_increments, run_to_rest, simulate, trajectory

NOMINAL_W_STAR = 1e-3 / DriveSI.nominal().T_c  # 1 ms pulse


def _mechanical_energy(drive: DriveSI, s: State) -> float:
    d = drive.r * s.q_m - s.q_l
    return 0.5 * drive.J_m * s.v_m**2 + 0.5 * drive.J_l * s.v_l**2 + 0.5 * drive.K_s * d**2


def _whole_ring_periods(drive: DriveSI, about: float) -> float:
    """A pulse width of a whole number of spring periods: the deflection rung up by the torque step at
    breakaway is back at exactly zero (with zero rate) when the torque steps down again."""
    period = 2 * math.pi / drive.omega
    return max(1, round(about / period)) * period


def _rigid_pulse(drive: DriveSI, amplitude_star: float, width: float) -> tuple[State, float]:
    """Pulse from rest, then coast past the rigid stopping time; return the state and the rigid travel."""
    j_eff = 1.0 + drive.r**2 * drive.J_l / drive.J_m
    w_star = width / drive.T_c
    rigid_travel = amplitude_star * (amplitude_star - 1.0) * w_star**2 / (2.0 * j_eff)
    s = simulate(drive, State(), amplitude_star * drive.f_m, width)
    s = simulate(drive, s, 0.0, 1.05 * (amplitude_star - 1.0) * width)
    return s, rigid_travel


# --- (1) rigid limit ---------------------------------------------------------------------------------------

def test_rigid_limit_motor_travel() -> None:
    """K* = 1e12, f_l = 0: the motor travels A (A-1) W*^2 / (2 J_eff) rad (non-integer A, so the compliant
    ringing does not cancel at the stop; its effect is O(1/K) ~ 1e-8 here)."""
    drive = DriveSI.from_nondim(K_star=1e12, J_l_star=2500.0, f_l_star=0.0)
    s, rigid = _rigid_pulse(drive, 7.3, _whole_ring_periods(drive, 1e-3))
    assert s.motor_stuck
    assert s.q_m == pytest.approx(rigid, rel=1e-6)


def test_rigid_formula_exact_when_ringing_cancels() -> None:
    """Nominal stiffness, integer A, W a whole number of periods: the stop falls on a whole number of
    periods after the pulse, where the coast ringing vanishes too, so the rigid formula holds exactly."""
    drive = DriveSI.from_nondim(K_star=1e6, J_l_star=2500.0, f_l_star=0.0)
    s, rigid = _rigid_pulse(drive, 3.0, _whole_ring_periods(drive, 1e-3))
    assert s.motor_stuck
    assert s.q_m == pytest.approx(rigid, rel=1e-11)


# --- (2) frictionless ringing ------------------------------------------------------------------------------

def test_frictionless_ringing_frequency_and_momentum() -> None:
    drive = replace(DriveSI.nominal(), f_m=0.0, f_l=0.0)
    d0 = 1e-6
    omega = math.sqrt(drive.K_s * (drive.r**2 / drive.J_m + 1.0 / drive.J_l))
    traj = trajectory(drive, State(q_l=-d0), 0.0, 3 * 2 * math.pi / omega, 41)
    deflection = drive.r * traj.q_m - traj.q_l
    for t, d in zip(traj.t, deflection):
        assert d == pytest.approx(d0 * math.cos(omega * t), abs=1e-10 * d0)
    # The spring is internal: J_m v_m + r J_l v_l stays zero.
    momentum = drive.J_m * traj.v_m + drive.r * drive.J_l * traj.v_l
    assert max(abs(momentum)) < 1e-12 * drive.J_l * omega * d0


# --- (3) energy balance ------------------------------------------------------------------------------------

def test_energy_balance_over_pulses_and_rest() -> None:
    """Input work = friction dissipation + kinetic + spring energy, over mixed pulses and coasting."""
    drive = DriveSI.nominal()
    s = State()
    input_work = 0.0
    for torque_star, width in ((2.0, 1e-3), (-3.5, 0.4e-3), (1.7, 2e-3), (0.0, 5e-3), (4.0, 0.7e-3)):
        torque = torque_star * drive.f_m
        before = s.q_m
        s = simulate(drive, s, torque, width)
        input_work += torque * (s.q_m - before)
        balance = input_work - s.friction_work - _mechanical_energy(drive, s)
        assert abs(balance) <= 1e-9 * s.friction_work
    s = run_to_rest(drive, s)
    assert s.input_work == pytest.approx(input_work, rel=1e-12)
    assert abs(input_work - s.friction_work - _mechanical_energy(drive, s)) <= 1e-9 * s.friction_work


# --- (4) Coulomb-damped load ringing with the motor stuck --------------------------------------------------

def test_load_ringing_loses_two_friction_deflections_per_half_period() -> None:
    drive = replace(DriveSI.nominal(), f_m=1.0)  # motor pinned: r K_s |d| << f_m
    step = 2 * drive.f_l / drive.K_s
    d0 = 5.25 * step
    half_period = math.pi / math.sqrt(drive.K_s / drive.J_l)
    s = State(q_l=-d0)
    for k in range(1, 5):
        s = simulate(drive, s, 0.0, half_period)
        assert s.motor_stuck and s.q_m == 0.0
        assert abs(s.v_l) < 1e-9 * d0 / half_period
        assert s.deflection(drive) == pytest.approx((-1) ** k * (d0 - k * step), rel=1e-9)
    # Next turning point: |d| = 0.25 step <= f_l / K_s, so the load sticks there for good.
    s = run_to_rest(drive, s)
    assert s.time == pytest.approx(5 * half_period, rel=1e-9)
    assert s.deflection(drive) == pytest.approx(-(d0 - 5 * step), rel=1e-9)


# --- (5) rest and no creep ---------------------------------------------------------------------------------

def test_nothing_moves_at_rest_without_torque() -> None:
    drive = DriveSI.nominal()
    s = simulate(drive, State(), 0.0, 1.0)
    assert (s.q_m, s.q_l, s.v_m, s.v_l, s.motor_stuck, s.load_stuck) == (0.0, 0.0, 0.0, 0.0, True, True)
    assert s.time == 1.0


def test_bodies_below_static_level_never_creep() -> None:
    drive = DriveSI.nominal()
    # Motor pushed at 90 % of its level for 10 s.
    s = simulate(drive, State(), 0.9 * drive.f_m, 10.0)
    assert s.motor_stuck and s.q_m == 0.0 and s.q_l == 0.0
    # Load preloaded to half its level by the spring.
    preloaded = State(q_l=-0.5 * drive.f_l / drive.K_s)
    s = simulate(drive, preloaded, 0.0, 10.0)
    assert s.load_stuck and s.q_l == preloaded.q_l and s.q_m == 0.0
    # Small pulses move the motor but leave the spring below f_l (final d ~ 0.37 f_l / K_s): the load
    # stays exactly put.
    increments, s = pulse_increments(drive, 1.005, NOMINAL_W_STAR, 3)
    assert increments == [0.0, 0.0, 0.0]
    assert s.q_m > 0.0 and s.q_l == 0.0


# --- protocol sanity ---------------------------------------------------------------------------------------

def test_pulse_train_rests_consistently_and_is_odd_in_amplitude() -> None:
    drive = DriveSI.nominal()
    up, s = pulse_increments(drive, 1.5, NOMINAL_W_STAR, 4)
    down, _ = pulse_increments(drive, -1.5, NOMINAL_W_STAR, 4)
    assert all(1e-7 < inc < 1e-6 for inc in up)  # 0.1 .. 1 um at the arm tip
    assert down == pytest.approx([-inc for inc in up], rel=1e-9)
    n_m = -drive.r * drive.K_s * s.deflection(drive)
    n_l = drive.K_s * s.deflection(drive)
    assert s.motor_stuck and s.load_stuck and s.v_m == 0.0 and s.v_l == 0.0
    assert abs(n_m) <= drive.f_m and abs(n_l) <= drive.f_l


def test_run_to_rest_raises_when_a_body_never_sticks() -> None:
    drive = replace(DriveSI.nominal(), f_l=0.0)
    with pytest.raises(RuntimeError):
        run_to_rest(drive, State(q_l=-1e-6), max_time=0.05)
