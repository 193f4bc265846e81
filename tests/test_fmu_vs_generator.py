"""The FMU against the independent log generator (tests/reference/generator: adaptive DOP853 with located events,
sharing no code with model.c) over whole 10 s logs at 5 kHz, for effects whose shape is the library's (viscous
friction on either side, a kinematic error of 2/rev and 4/rev): started from the generator's own initial state and
fed its torques sample by sample, the FMU must retrace the generator's noise-free load angle to 0.05 noise sigmas
(the two integrators' own errors: 0.016 sigmas over the 21 rad of motor travel of a torque-step log, 5e-11 of it).

This is the diagnosis's premise: a model at the truth reproduces the log. Where it did not (two-effect log 5305: a
motor that stopped and broke away again inside one 0.2 ms sample, a stop the FMU's end-of-substep check slid
through at 6.13 s), every candidate with that effect predicted the held-back data 1.3x the noise and the kinematic
error went unnamed."""
from __future__ import annotations

import numpy as np
import pytest

from ident import DriveParams, Plant
from tests.reference.generator import logs as generator


def _library_drive(truth: generator.Truth) -> DriveParams:
    si, effects = truth.si, truth.effects
    kw = {k: si[k] for k in ("J_m", "f_m", "K_s", "J_l", "f_l", "r", "arm_length", "encoder_counts_per_rev")}
    kw.update(b_m=effects.get("b_m", 0.0), b_l=effects.get("b_l", 0.0))
    ke = effects.get("kinematic_error")
    if ke:
        kw.update(kinematic_error=ke["amp2"], kinematic_error_phase=ke["phase2"], kinematic_error_4=ke["amp4"],
                  kinematic_error_4_phase=ke["phase4"])
    return DriveParams(**kw)


LOGS = {
    "two-effect 5305 (motor viscous, kinematic error)":
        lambda: generator.two_effect_case(5305, excitation="default", duration_s=10.0, rate_hz=5000.0),
    "5102 kinematic error, default design":
        lambda: generator.diagnosis_case(5102, "kinematic_error", "medium", "default", duration_s=10.0,
                                         rate_hz=5000.0),
    "5103 load viscous, torque steps":
        lambda: generator.diagnosis_case(5103, "viscous_load", "strong", "steps", duration_s=10.0, rate_hz=5000.0),
}


@pytest.mark.parametrize("name", list(LOGS))
def test_the_fmu_retraces_the_generators_log(name: str) -> None:
    g = LOGS[name]()
    truth = g.truth
    p = _library_drive(truth)
    q0, d0 = truth.initial_motor_angle_rad, truth.initial_deflection_rad
    with Plant(p) as plant:
        plant.reset(p, q_m_start=q0, q_l_start=p.load_angle_at(q0, d0), v_m_start=0.0, v_l_start=0.0)
        out = plant.trajectory(g.motor_torque_Nm[:-1], 1.0 / truth.sample_rate_hz, ("q_m", "q_l"))
    assert np.ptp(g.true_motor_pos_rad) > 1e3 * truth.noise_sigma_rad / p.r  # the motor moved: no trivial match
    load = np.abs(out[:, 1] - g.true_load_pos_rad) / truth.noise_sigma_rad
    worst = int(np.argmax(load))
    assert load[worst] < 0.05, (f"{name}: the load leaves the generator's by {load[worst]:.3g} noise sigmas at "
                                f"t = {worst / truth.sample_rate_hz:.4f} s")
