"""This thread's idle plants (``ident.model.pool``): a plant handed out again gives what a new ``Plant`` gives, to
the last bit, and two users never hold the same one; and the cheap per-simulation steps under them (a reset's
writes, a drive changed in a few fields) give what the full ones give.

The drives and starts here are drawn for this file (NumPy's generator seeded 4306, a seed in neither the product
nor its other tests), each with effects on, so that a state an earlier user left behind (a hysteresis element, a
stuck body, a counter of work) would show in the next trajectory."""
from __future__ import annotations

import numpy as np
import pytest

from ident import DriveParams, ParameterError, Plant
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


def test_threads_opening_plants_at_once_read_the_model_description_one_at_a_time(monkeypatch) -> None:
    """libxml2 sets up its XML-schema types on a process's first schema parse without a lock, so two threads that
    opened their first plants at once (a sweep's lanes) could fail fmpy's schema check ("Document is not valid XML
    Schema", twice in CI). The reads are serialized: the reader below, slowed so that unserialized reads would
    overlap, never sees a second one in flight."""
    import threading
    import time

    import fmpy

    real, inside, most = fmpy.read_model_description, [0], [0]
    guard = threading.Lock()

    def slow_read(*args, **kwargs):
        with guard:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        time.sleep(0.05)
        try:
            return real(*args, **kwargs)
        finally:
            with guard:
                inside[0] -= 1

    monkeypatch.setattr(fmpy, "read_model_description", slow_read)
    start, plants = threading.Barrier(4), []

    def open_one() -> None:
        start.wait()
        plants.append(Plant(DriveParams()))

    threads = [threading.Thread(target=open_one) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for p in plants:
        p.close()
    assert len(plants) == 4 and most[0] == 1


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


@pytest.mark.parametrize("fmi_version", [2, 3])
def test_a_reset_writes_every_parameter_and_start_as_a_new_plant_reads_them(fmi_version: int) -> None:
    """``Plant.reset`` writes the drive and the start through its own arrays (not fmpy's ``setReal``): after a run
    with one drive, a reset to another (an integer parameter, the encoder's counts, changed too) gives what a new
    ``Plant`` of that drive gives, on both FMI versions."""
    torque = default_excitation(DriveParams(), 0.2, 5000.0)
    first, second = _drive(), _drive().with_values(encoder_counts_per_rev=4096)
    start = _start()
    with Plant(first, fmi_version=fmi_version) as plant, Plant(second, fmi_version=fmi_version, **start) as new:
        count = new.sample().encoder_count
        _run(plant, torque)
        assert plant.reset(second, **start).encoder_count == count
        got, want = _run(plant, torque), _run(new, torque)
        np.testing.assert_array_equal(got[0], want[0])
        assert got[1] == want[1] and plant.sample() == new.sample()
    with Plant(first, fmi_version=fmi_version, **start) as other:   # the integer matters: the counts differ
        assert other.sample().encoder_count != count


def test_a_changed_drive_checks_what_changed_and_equals_one_made_whole() -> None:
    """``DriveParams.with_values`` checks only the fields it changes (the others were checked when their drive was
    made): the result equals a drive made from all its values, an integer comes out an integer, and a changed value
    out of its range is refused by name."""
    base = _drive()
    got = base.with_values(K_star=2.5e6, J_l_star=3100.0, b_l=2e-6, encoder_counts_per_rev=8192.0)
    want = DriveParams(**{**base.to_dict(), "K_s": 2.5e6 * base.f_m, "J_l": 3100.0 * base.J_m, "b_l": 2e-6,
                          "encoder_counts_per_rev": 8192})
    assert got == want and [type(v) for v in got.to_dict().values()] == [type(v) for v in want.to_dict().values()]
    assert base.with_values() is base
    with pytest.raises(ParameterError, match="b_m"):
        base.with_values(b_m=-1.0)
    with pytest.raises(ParameterError, match="K_s"):
        base.with_values(K_star=-3.0)
