"""The effect library's two copies agree: the CasADi terms of ident.model.effects and the C model of the FMU.

The FMU simulates a pulse train with every effect on; at every sample the CasADi model is evaluated on the FMU's
own state and must give the same deflection, spring torque and friction torques (slipping samples), and the same
accelerations (finite differences of the FMU's velocities over a short step)."""
from __future__ import annotations

import numpy as np
import pytest

from ident.model import effects as E
from ident.model.params import DriveParams
from ident.model.plant import Plant

ALL_ON = dict(b_m=1e-4, b_l=0.5, stribeck_ratio=0.5, stribeck_velocity=2e-4, friction_asymmetry=0.2,
              hardening=3e6, hysteresis_torque=2e-3, hysteresis_stiffness=1e4, kinematic_error=1e-5,
              kinematic_error_phase=0.7, viscous_asymmetry=0.3, kinematic_error_4=4e-6, kinematic_error_4_phase=-1.9)
OUTS = ("q_m", "q_l", "v_m", "v_l", "hysteresis_state", "deflection", "spring_torque", "motor_friction_torque",
        "load_friction_torque")


@pytest.fixture(scope="module", params=[(2.0, 1.0, 2.0), (1.0, 2.0, 2.0), (1.5, 1.5, 2.0), (2.0, 1.0, 1.0)],
                ids=["gaussian-dahl", "exponential-dahl-2", "delta-1.5-dahl-1.5", "hardening-exponent-1"])
def run(request):
    """The pulse train with every effect on, for each Stribeck decay exponent (``stribeck_shape``), Dahl exponent
    (``hysteresis_exponent``) and the hardening of exponent 1 beside the cubic (``hardening_exponent``, stiffening
    as the cubic does at 5e-5 rad)."""
    shape, exponent, hardening = request.param
    p = DriveParams().with_values(**ALL_ON, stribeck_shape=shape, hysteresis_exponent=exponent,
                                  hardening_exponent=hardening, hardening_deflection=5e-5)
    dt = 1e-4
    torque = np.zeros(4000)
    for k, a in enumerate((3.0, -2.5, 4.0, -1.8)):
        torque[k * 1000:k * 1000 + 10] = a * p.f_m
        torque[k * 1000 + 300:k * 1000 + 600] = np.sign(a) * 1.3 * p.f_m  # a slow slide
    with Plant(p) as plant:
        traj = plant.trajectory(torque, dt, OUTS)
    return p, torque, dt, {k: traj[:, i] for i, k in enumerate(OUTS)}


def test_outputs_equal_the_casadi_terms(run):
    p, torque, dt, x = run
    f = E.slip_dynamics(p.to_dict())
    both = (x["v_m"] != 0) & (x["v_l"] != 0)
    assert both.sum() > 500
    state = np.vstack([x["q_m"], x["q_l"], x["v_m"], x["v_l"], x["hysteresis_state"]])
    u = np.append(torque, 0.0)
    _, y = f(state[:, both], u[both][None, :])  # CasADi maps over the columns
    y = np.array(y)
    for i, name in enumerate(("deflection", "spring_torque", "motor_friction_torque", "load_friction_torque")):
        ref = x[name][both]
        scale = np.max(np.abs(ref))
        assert scale > 0
        np.testing.assert_allclose(y[i], ref, rtol=0, atol=1e-12 * scale, err_msg=name)


def test_accelerations_equal_the_casadi_model(run):
    """Step the FMU by 0.1 us from sampled states (restored exactly) and compare the velocity change with the CasADi
    model's acceleration (hysteresis off: its state is not a start value): O(h) agreement."""
    p, torque, dt, x = run
    p = p.with_values(hysteresis_torque=0.0)  # the Dahl state cannot be set as a start value; see the test above
    f = E.slip_dynamics(p.to_dict())
    h = 1e-7
    with Plant(p) as plant:
        checked = 0
        for k in range(50, 4000, 97):
            if x["v_m"][k] == 0 or x["v_l"][k] == 0:
                continue
            plant.reset(p, q_m_start=x["q_m"][k], q_l_start=x["q_l"][k], v_m_start=x["v_m"][k],
                        v_l_start=x["v_l"][k])
            s = plant.step(float(torque[k]), h)
            xdot, _ = f([x["q_m"][k], x["q_l"][k], x["v_m"][k], x["v_l"][k], 0.0], float(torque[k]))
            xdot = np.array(xdot).ravel()
            a_m, a_l = (s.v_m - x["v_m"][k]) / h, (s.v_l - x["v_l"][k]) / h
            assert a_m == pytest.approx(xdot[2], rel=1e-4, abs=1e-6 * abs(xdot[2]) + 1e-9)
            assert a_l == pytest.approx(xdot[3], rel=1e-4, abs=1e-6 * abs(xdot[3]) + 1e-9)
            checked += 1
    assert checked >= 5


def test_static_band_and_registry():
    lo, hi = E.static_band(2.0, 0.25, 0.5)
    assert (float(lo), float(hi)) == pytest.approx((-2.0 * 0.75 * 1.5, 2.0 * 1.25 * 1.5))
    # every effect's parameters are FMU parameters with a default-off start value
    from fmu_build import variables as V

    for name, eff in E.EFFECTS.items():
        for var in eff.fit_vars:
            assert var.param in V.BY_NAME and V.BY_NAME[var.param].causality == "parameter", (name, var.param)
    assert set(E.EFFECT_DEFAULTS) == {v.name for v in V.VARIABLES if 100 <= v.vr < 200}
    for k, v in E.EFFECT_DEFAULTS.items():
        assert V.BY_NAME[k].start == v
    assert E.active_effects(DriveParams().to_dict()) == []
    assert E.active_effects(DriveParams(b_l=0.1, hardening=1.0).to_dict()) == ["viscous_load", "hardening"]
