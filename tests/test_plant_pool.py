"""This thread's idle plants (``ident.model.pool``): a plant handed out again gives what a new ``Plant`` gives, to
the last bit, and two users never hold the same one.

The drives and starts here are drawn for this file (NumPy's generator seeded 4306, a seed in neither the product
nor its other tests), each with effects on, so that a state an earlier user left behind (a hysteresis element, a
stuck body, a counter of work) would show in the next trajectory."""
from __future__ import annotations

import numpy as np
import pytest

from ident import DriveParams, Plant
from ident.fitting.identify import OutputError
from ident.fitting.synthetic import default_excitation, synthetic_log
from ident.model import pool

RNG = np.random.default_rng(4306)


def _drive() -> DriveParams:
    u = RNG.uniform
    return DriveParams(K_s=u(5e3, 2e4), J_l=u(0.02, 0.1), f_l=u(5e-4, 3e-3), b_m=u(0, 1e-5),
                       hysteresis_torque=u(1e-5, 1e-4), hysteresis_stiffness=u(3e3, 3e4),
                       stribeck_ratio=u(0.1, 0.5), stribeck_velocity=u(1e-4, 1e-2), kinematic_error=u(0, 5e-5))


def _start() -> dict[str, float]:
    return dict(q_m_start=float(RNG.uniform(-3, 3)), q_l_start=float(RNG.uniform(-0.03, 0.03)))


def _run(plant: Plant, torque: np.ndarray) -> tuple[np.ndarray, float]:
    return plant.trajectory(torque, 2e-4, ("q_m", "q_l", "v_m", "v_l")), plant.model_evaluations()


def test_a_plant_handed_out_again_gives_what_a_new_one_gives() -> None:
    torque = default_excitation(DriveParams(), 0.4, 5000.0)
    first, second = _drive(), _drive()
    plant = pool.take(first, **_start())
    _run(plant, torque)                       # leaves its hysteresis state, its work count, a moving motor
    pool.give_back(plant)
    again = pool.take(second)                 # every initial state not given: at rest, as a new Plant starts
    assert again is plant
    with Plant(second) as new:
        want = _run(new, torque)
    got = _run(again, torque)
    np.testing.assert_array_equal(got[0], want[0])
    assert got[1] == want[1]
    start = _start()
    again.reset(first, **start)
    with Plant(first, **start) as new:
        np.testing.assert_array_equal(_run(again, torque)[0], _run(new, torque)[0])
    pool.give_back(again)


def test_two_users_never_share_a_plant() -> None:
    a, b = pool.take(DriveParams()), pool.take(DriveParams())
    assert a is not b
    pool.give_back(a)
    pool.give_back(a)                         # given back twice: still handed out once
    c, d = pool.take(DriveParams()), pool.take(DriveParams())
    assert c is a and d is not a and d is not b
    b.close()
    pool.give_back(b)                         # a closed plant is not kept
    for p in (c, d):
        p.close()
    e = pool.take(DriveParams())
    assert e is not b and e.fmu is not None
    e.close()


def test_a_block_that_raised_closes_its_plant() -> None:
    with pytest.raises(KeyError):
        with pool.pooled_plant(DriveParams()) as plant:
            raise KeyError("stopped in the middle of a call")
    assert plant.fmu is None
    with pool.pooled_plant(DriveParams()) as other:
        assert other is not plant


def test_a_closed_problem_gives_its_plant_back_and_cannot_simulate() -> None:
    log = synthetic_log(DriveParams(), duration_s=0.2, seed=4306)
    problem = OutputError(log, DriveParams())
    plant = problem.plant
    problem.close()
    problem.close()                           # twice: the plant is idle once
    assert problem.plant is None
    nxt, other = OutputError(log, DriveParams()), OutputError(log, DriveParams())
    assert nxt.plant is plant and other.plant is not plant
    nxt.close()
    other.close()
