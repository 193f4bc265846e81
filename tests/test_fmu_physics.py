"""The FMU's physics against independent truth: analytic solutions, energy balance, step-size independence.

Every test drives the real FMU through ``ident.Plant`` (fmpy underneath), for FMI 2.0 and 3.0 alike.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from ident import DriveParams, Plant

NOMINAL = DriveParams()


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def fmi(request) -> int:
    return request.param


def state(plant: Plant) -> np.ndarray:
    s = plant.sample()
    return np.array([s.q_m, s.q_l, s.v_m, s.v_l])


def assert_state_close(a: np.ndarray, b: np.ndarray, rtol: float, scale: np.ndarray) -> None:
    """Relative agreement per component, relative to the larger of the value and the component's scale."""
    tol = rtol * np.maximum(np.maximum(abs(a), abs(b)), scale)
    assert np.all(abs(a - b) <= tol), f"states differ: {a} vs {b} (diff {a - b}, tol {tol})"


# ---------------------------------------------------------------------------------- step-size independence -----

SCENARIOS = {
    # torque held over 1 s: motor slides all the time, the load is dragged through stick-slip ringing
    "driven": (dict(), 1.5 * NOMINAL.f_m),
    # released from a moving start with zero torque: slides, sticks, load rings down with Coulomb decay
    "coasting": (dict(v_m_start=2.0), 0.0),
    # torque just below breakaway, spring wound up: the ringing load drags the motor through stick-slip
    "stick_slip": (dict(q_l_start=-2e-5), 0.95 * NOMINAL.f_m),
}


@pytest.mark.parametrize("name", sorted(SCENARIOS))
def test_state_does_not_depend_on_communication_step(fmi: int, name: str) -> None:
    initial, torque = SCENARIOS[name]
    results = []
    with Plant(fmi_version=fmi, **initial) as plant:
        for n in (1, 1000, 100_000):
            plant.reset()
            for _ in range(n):
                plant.step(torque, 1.0 / n)
            results.append((state(plant), plant.energy(), plant.sample().at_rest))
    scale = np.array([1e-3, 1e-5, 1e-2, 1e-3])  # rad, rad, rad/s, rad/s: floors for components that end near 0
    for s, energy, rest in results[1:]:
        assert_state_close(s, results[0][0], 1e-9, scale)
        assert np.allclose(energy, results[0][1], rtol=1e-9, atol=1e-15)
        assert rest == results[0][2]


def test_nothing_moves_at_rest_bit_exact() -> None:
    """A million steps without torque (1000 s): every sample's angles are the start's to the bit, every speed 0."""
    with Plant() as plant:
        first = plant.sample()
        out = plant.trajectory(np.zeros(999_999), 1e-3, ("q_m", "q_l", "v_m", "v_l"))
        assert (out == [first.q_m, first.q_l, 0.0, 0.0]).all()
        s = plant.step(0.0, 1e-3)
        assert (s.q_m, s.q_l, s.v_m, s.v_l) == (first.q_m, first.q_l, 0.0, 0.0)
        assert s.at_rest


def test_body_pressed_below_static_level_never_creeps() -> None:
    # motor pushed with 99.9 % of f_m; load wound against its spring to 99 % of f_l: neither may move a bit
    q_l0 = -0.99 * NOMINAL.f_l / NOMINAL.K_s
    with Plant(q_l_start=q_l0) as plant:
        for _ in range(20_000):
            s = plant.step(0.999 * NOMINAL.f_m, 5e-4)
        assert (s.q_m, s.q_l, s.v_m, s.v_l) == (0.0, q_l0, 0.0, 0.0)
        assert s.motor_stuck and s.load_stuck


# ---------------------------------------------------------------------------------- analytic truths -----------

def rest_motor_angle(plant: Plant, dt: float) -> float:
    s = plant.sample()
    for _ in range(100_000):
        if s.motor_stuck:
            return s.q_m
        s = plant.step(0.0, dt)
    raise AssertionError("motor never stuck")


@pytest.mark.parametrize("A", [1.5, 3.0, 10.0])
def test_rigid_limit_pulse_displacement(fmi: int, A: float) -> None:
    """Very stiff spring, no load friction: the drive is one rigid body J_eff = 1 + r^2 J_l* (non-dimensional).

    A pulse tau* = A for W* from rest moves the motor by A (A - 1) W*^2 / (2 J_eff) radians.
    """
    p = DriveParams.from_nondim(K_star=1e14, J_l_star=2500, f_l_star=0.0)
    W_star = 1e-3 / p.T_c
    J_eff = 1 + p.r**2 * p.J_l_star
    expected = A * (A - 1) * W_star**2 / (2 * J_eff)
    with Plant(p, fmi_version=fmi) as plant:
        plant.step(A * p.f_m, 1e-3)
        q = rest_motor_angle(plant, 1e-4)
    assert q == pytest.approx(expected, rel=1e-6)


def test_frictionless_ringing_frequency(fmi: int) -> None:
    """No friction, initial deflection d0, zero momentum: d(t) = d0 cos(w t), w = sqrt(K* (r^2 + 1/J_l*)) / T_c."""
    p = NOMINAL.with_values(f_m=0.0, f_l=0.0)
    d0 = 1e-6
    # zero total momentum: J_m v_m + J_l v_l / r ... both start at rest, so the centre of mass stays put
    w = math.sqrt(p.K_s * (p.r**2 / p.J_m + 1 / p.J_l))
    w_nd = math.sqrt(NOMINAL.K_star * (p.r**2 + 1 / NOMINAL.J_l_star)) / NOMINAL.T_c  # paper's form, same drive
    assert w == pytest.approx(w_nd, rel=1e-12)
    dt = 0.37e-3
    with Plant(p, fmi_version=fmi, q_l_start=-d0) as plant:
        for k in range(1, 2001):
            s = plant.step(0.0, dt)
            d = s.spring_torque / p.K_s
            assert d == pytest.approx(d0 * math.cos(w * k * dt), abs=1e-9 * d0), f"step {k}"


def test_energy_balance(fmi: int) -> None:
    """Input work = friction dissipation + kinetic + spring energy, to 1e-9 relative, through a pulse train."""
    p = NOMINAL
    with Plant(p, fmi_version=fmi) as plant:
        schedule = [(3 * p.f_m, 1e-3), (0.0, 0.02), (-5 * p.f_m, 7e-4), (0.0, 0.013), (2.2 * p.f_m, 2e-3)]
        for torque, duration in schedule * 4:
            s = plant.step(torque, duration)
            w_in, w_fric = plant.energy()
            kinetic = 0.5 * p.J_m * s.v_m**2 + 0.5 * p.J_l * s.v_l**2
            spring = 0.5 * s.spring_torque**2 / p.K_s
            assert w_in - w_fric == pytest.approx(kinetic + spring, rel=1e-9, abs=1e-9 * w_in)
        assert w_fric > 0.5 * w_in  # friction did take most of it: the check is not trivially satisfied


def test_coulomb_decay_of_load_ringing(fmi: int) -> None:
    """Motor stuck, load ringing: each half period (pi / sqrt(K_s/J_l)) loses 2 f_l/K_s of deflection amplitude."""
    p = NOMINAL
    d0 = 1.07e-6
    half = math.pi / math.sqrt(p.K_s / p.J_l)
    step = 2 * p.f_l / p.K_s
    n_half = math.ceil((d0 - p.f_l / p.K_s) / step)  # it stops at the first turning point with |d| <= f_l/K_s
    with Plant(p, fmi_version=fmi, q_l_start=-d0) as plant:
        amplitudes = [d0]
        for k in range(n_half):
            s = plant.step(0.0, half)
            assert s.motor_stuck
            assert not s.load_stuck or k == n_half - 1  # it may stick exactly at the last turning point
            amplitudes.append(abs(s.spring_torque) / p.K_s)
        s = plant.step(0.0, 1e-6)  # the last stop falls on the communication point: look just after it
        assert s.load_stuck and s.motor_stuck
        final = abs(s.spring_torque) / p.K_s
    expected = [d0 - k * step for k in range(n_half + 1)]
    np.testing.assert_allclose(amplitudes, expected, rtol=1e-9, atol=1e-9 * d0)
    assert final == pytest.approx(expected[-1], rel=1e-9, abs=1e-9 * d0) and final <= p.f_l / p.K_s


def test_encoder_and_arm_outputs() -> None:
    p = NOMINAL
    with Plant(p) as plant:
        s = plant.step(3 * p.f_m, 1e-3)
        s = plant.run_to_rest()
        assert s.encoder_count == math.floor(s.q_m / p.count_rad)
        assert s.arm_position == pytest.approx(p.arm_length * s.q_l, rel=1e-15)
        assert s.spring_torque == pytest.approx(p.K_s * (p.r * s.q_m - s.q_l), rel=1e-9, abs=1e-15)
    assert p.count_at_arm_m == pytest.approx(1.50e-6, rel=2e-3)  # physics.md: one count = 1.50 um at the arm
