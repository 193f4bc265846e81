"""Tests of the independent reference log generator (``tests/reference/generator``).

The generator is the truth that identification (issue 21) and diagnosis (issue 16) are tested against, so it is
checked here by properties that do not depend on it: the older, separately written event-driven integrator
(``tests/reference/event_driven.py``) on the base model; its two engines against each other; convergence in the
integration tolerance; energy balance; analytic solutions (Dahl branches, kinematic-error lines, breakaway
levels); exact stick-slip; the sensor model; determinism; and the product's own reader on the written files.

Tolerances are set from the sensor: the smallest load noise the generator draws is 1 nm at a 0.5 m arm, 2e-9 rad;
trajectories must agree to 1e-11 rad (1/200 of it), "far below the sensor noise".
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.reference import event_driven as ed
from tests.reference.generator import excitations as exc
from tests.reference.generator import logs
from tests.reference.generator.effects import (
    CLASSES,
    LIBRARY_EFFECTS,
    SEARCH_TOLERANCE,
    VARIANTS,
    WEAK_SNR,
)
from tests.reference.generator.engines import RKEngine, simulate
from tests.reference.generator.linear import LinearEngine
from tests.reference.generator.plant import (
    CubicStiffness,
    Dahl,
    Drive,
    Effects,
    FrictionRipple,
    HybridPlant,
    KinematicError,
    MaxwellSlip,
    Stribeck,
    ThreeSlopeStiffness,
)
from tests.reference_adapter import read_back

TRAJECTORY_TOL_RAD = 1e-11          # 1/200 of the smallest load noise drawn (1 nm / 0.5 m)
SMALLEST_SIGMA_RAD = 1e-9 / 0.5


def _pulses(drive: Drive, rate: float, seconds: float, seed: int) -> np.ndarray:
    """Bidirectional pulses and one slow move: every kind of mode change within a short run."""
    rng = np.random.default_rng(seed)
    n = round(seconds * rate)
    tau = np.zeros(n)
    k = int(0.01 * rate)
    while k < n:
        width = max(1, int(rng.uniform(0.5e-3, 2e-3) * rate))
        tau[k:k + width] = rng.choice((-1, 1)) * rng.uniform(1.5, 5.0)
        k += width + int(rng.uniform(0.02, 0.06) * rate)
    move = slice(int(0.4 * n), int(0.55 * n))
    tau[move] = 1.4
    return tau * drive.f_m


def _run(drive: Drive, effects: Effects, tau: np.ndarray, rate: float, engine_cls=RKEngine, d0_frac: float = 0.4,
         keep_states: bool = False, track_energy: bool = False, **engine_kw):
    plant = HybridPlant(drive, effects, track_energy=track_energy)
    x, mode = plant.initial_state(0.0, d0_frac * drive.f_l / drive.K_s)
    record, _ = simulate(plant, engine_cls(plant, **engine_kw), x, mode, 1.0 / rate, lambda k, q: tau[k],
                         tau.size, keep_states)
    return plant, record


def _drive(seed: int) -> Drive:
    return logs.draw_drive(seed)


# ------------------------------------------------------------------------------------ accuracy ------------------

@pytest.mark.parametrize("seed", [4103, 4110])
def test_base_model_matches_event_driven_reference(seed: int) -> None:
    """A drawn drive from a wound start under pulses and a move: every sample of both engines agrees with the
    independent solve_ivp reference (rtol 1e-12, located events) to 1e-11 rad on the load, 1e-11/r on the motor."""
    drive, rate = _drive(seed), 5000.0
    tau = _pulses(drive, rate, 0.25, seed)
    ref_drive = ed.DriveSI(J_m=drive.J_m, f_m=drive.f_m, K_s=drive.K_s, J_l=drive.J_l, f_l=drive.f_l, r=drive.r,
                           arm_length=drive.arm_length)
    state = ed.State(q_l=-0.4 * drive.f_l / drive.K_s)
    q_m, q_l = [state.q_m], [state.q_l]
    for torque in tau:
        state = ed.simulate(ref_drive, state, float(torque), 1.0 / rate)
        q_m.append(state.q_m)
        q_l.append(state.q_l)
    for engine_cls in (LinearEngine, RKEngine):
        _, rec = _run(drive, Effects(), tau, rate, engine_cls)
        assert np.ptp(rec.q_m) > 10 * drive.count_rad      # it moved
        assert rec.events > 20
        assert np.max(np.abs(rec.q_l - np.array(q_l))) <= TRAJECTORY_TOL_RAD, engine_cls.__name__
        assert np.max(np.abs(rec.q_m - np.array(q_m))) <= TRAJECTORY_TOL_RAD / drive.r, engine_cls.__name__


PIECEWISE_LINEAR = {
    "viscous": Effects(b_m=3e-5, b_l=0.5),
    "asymmetric": Effects(asymmetry_m=0.2, asymmetry_l=-0.3),
    "three_slope": Effects(stiffness=ThreeSlopeStiffness(3e-6, 8e-6, 1.6, 3.0)),
    "maxwell": Effects(hysteresis=MaxwellSlip((2e3, 1e3, 5e2), (2e-3, 4e-3, 6e-3))),
    "actuator_lag": Effects(actuator_lag_s=3e-4),
}


@pytest.mark.parametrize("name", PIECEWISE_LINEAR)
def test_engines_agree_on_piecewise_linear_effects(name: str) -> None:
    """The closed-form engine (matrix exponential, polynomial guards) and adaptive DOP853 (Hermite dips, secant
    on re-steps) share only the plant's equations: same events, same trajectory to 1e-11 rad."""
    drive, rate = Drive(), 5000.0
    tau = _pulses(drive, rate, 0.3, 11)
    _, lin = _run(drive, PIECEWISE_LINEAR[name], tau, rate, LinearEngine)
    _, rk = _run(drive, PIECEWISE_LINEAR[name], tau, rate, RKEngine)
    _, base = _run(drive, Effects(), tau, rate, LinearEngine)
    assert lin.events == rk.events
    assert np.max(np.abs(lin.q_l - rk.q_l)) <= TRAJECTORY_TOL_RAD
    assert np.max(np.abs(lin.q_m - rk.q_m)) <= TRAJECTORY_TOL_RAD / drive.r
    assert np.max(np.abs(lin.q_l - base.q_l)) > 1e3 * TRAJECTORY_TOL_RAD   # the effect does something


NONLINEAR = {
    "stribeck_exponential": Effects(stribeck=Stribeck(0.4, 2e-3)),
    "stribeck_gaussian_static": Effects(stribeck=Stribeck(0.3, 2e-3, "gaussian", 0.6)),
    "cubic": Effects(stiffness=CubicStiffness(2e9)),
    "dahl": Effects(hysteresis=Dahl(1e-3, 1e3, 1.5)),
    "kinematic_error": Effects(kinematic_error=KinematicError(2e-5, 0.4, 6e-6, 2.0)),
    "friction_ripple": Effects(friction_ripple=FrictionRipple(0.2, 2, 0.5)),
}


@pytest.mark.parametrize("name", NONLINEAR)
def test_nonlinear_effects_converge_in_rtol(name: str) -> None:
    """Default rtol (1e-10) against 100x tighter: the difference bounds the default's error; below 1e-11 rad."""
    drive, rate = Drive(), 5000.0
    tau = _pulses(drive, rate, 0.3, 12)
    _, default = _run(drive, NONLINEAR[name], tau, rate, rtol=logs.RTOL)
    _, tight = _run(drive, NONLINEAR[name], tau, rate, rtol=logs.RTOL / 100)
    _, base = _run(drive, Effects(), tau, rate, LinearEngine)
    assert np.max(np.abs(default.q_l - tight.q_l)) <= TRAJECTORY_TOL_RAD
    assert np.max(np.abs(default.q_l - base.q_l)) > 1e3 * TRAJECTORY_TOL_RAD


@pytest.mark.parametrize("name", list(PIECEWISE_LINEAR) + list(NONLINEAR))
def test_energy_balance(name: str) -> None:
    """Input work = kinetic + spring energy + friction work + work on the hysteresis elements, at every sample
    (integrated as extra states; measured ~1e-15 of the input work; 1e-9 allows for the tolerance)."""
    effects = {**PIECEWISE_LINEAR, **NONLINEAR}[name]
    drive, rate = Drive(), 5000.0
    plant, rec = _run(drive, effects, _pulses(drive, rate, 0.3, 13), rate, keep_states=True, track_energy=True)
    w = plant.i_work
    stored = np.array([plant.energy(list(s)) for s in rec.states])
    balance = rec.states[:, w] - rec.states[:, w + 1] - rec.states[:, w + 2] - (stored - stored[0])
    assert rec.states[-1, w] > 0.0 and rec.states[-1, w + 1] > 0.0
    assert np.max(np.abs(balance)) <= 1e-9 * rec.states[-1, w]


def test_maxwell_slip_is_passive_and_bounded() -> None:
    """Maxwell-slip elements: |w_i| <= F_i always, and what they dissipate (work done on them minus what their
    springs hold) never decreases -- the loop area is dissipation."""
    effects = PIECEWISE_LINEAR["maxwell"]
    drive, rate = Drive(), 5000.0
    plant, rec = _run(drive, effects, _pulses(drive, rate, 0.3, 14), rate, keep_states=True, track_energy=True)
    F = np.array(effects.hysteresis.break_torques)
    w = rec.states[:, plant.i_w:plant.i_w + plant.n_elements]
    assert np.all(np.abs(w) <= F * (1 + 1e-12))
    assert np.any(np.isclose(np.abs(w), F, rtol=1e-12))                    # elements did slide
    dissipated = rec.states[:, plant.i_work + 2] - np.array([plant.hysteresis_stored(list(s)) for s in rec.states])
    assert np.all(np.diff(dissipated) >= -1e-15 * dissipated[-1])
    assert dissipated[-1] > 0.0


def test_dahl_branches_follow_the_analytic_solution() -> None:
    """Along a stretch of monotone deflection, Dahl (exponent 1) gives z = s H - (s H - z_a) exp(-s sigma
    (d - d_a) / H) with s the direction of motion. The integrated z matches it to 1e-10 N m (5e-8 H), a torque
    that moves the load by 1e-14 rad through the 1e4 N m/rad spring (measured: 7e-12 N m, where z swings by half
    of H within one sample)."""
    dahl = Dahl(2e-3, 2e3, 1.0)
    drive, rate = Drive(), 5000.0
    plant, rec = _run(drive, Effects(hysteresis=dahl), _pulses(drive, rate, 0.3, 15), rate, keep_states=True)
    d = drive.r * rec.states[:, 0] - rec.states[:, 1]
    z = rec.states[:, plant.i_z]
    step = np.sign(np.diff(d))
    checked = 0
    k = 0
    while k < step.size:
        j = k
        while j < step.size and step[j] == step[k]:
            j += 1
        if step[k] != 0 and j - k >= 6:   # samples k+1 .. j-1 are inside one monotone stretch
            s, a = step[k], k + 1
            model = s * dahl.torque - (s * dahl.torque - z[a]) * np.exp(-s * dahl.stiffness * (d[a:j] - d[a])
                                                                        / dahl.torque)
            assert np.max(np.abs(z[a:j] - model)) <= 1e-14 * drive.K_s
            checked += j - a
        k = j
    assert checked > 200


def test_stribeck_shapes() -> None:
    """The sliding friction law of each shape at 0+, v_s and 2 v_s; the static band above it when separate."""
    drive = Drive()
    for shape, decay2 in (("exponential", math.exp(-2)), ("gaussian", math.exp(-4))):
        for static in (None, 0.9):
            plant = HybridPlant(drive, Effects(stribeck=Stribeck(0.5, 1e-3, shape, static)))
            law = plant.frictions[1].sliding_fn(1)
            f = drive.f_l
            assert law(1e-15, 0.0) == pytest.approx(f * 1.5, rel=1e-9)
            assert law(1e-3, 0.0) == pytest.approx(f * (1 + 0.5 * math.exp(-1)), rel=1e-12)
            assert law(2e-3, 0.0) == pytest.approx(f * (1 + 0.5 * decay2), rel=1e-12)
            assert plant.frictions[1].band(0.0)[1] == pytest.approx(f * (1 + (static or 0.5)), rel=1e-12)
            motor = plant.frictions[0].sliding_fn(-1)      # motor: v_s / r, same shape
            assert motor(-1e-3 / drive.r, 0.0) == pytest.approx(-drive.f_m * (1 + 0.5 * math.exp(-1)), rel=1e-12)


@pytest.mark.parametrize("static", [None, 1.0])
def test_breakaway_at_the_static_level_then_overshoot(static: float | None) -> None:
    """A slow torque ramp: the motor stays exactly put until the command exceeds the static level f_m (1 + s0),
    and moves from the next sample on; held just above breakaway, Stribeck's lower sliding friction makes the
    motor run away far beyond a Coulomb-only motor whose level is the same static level."""
    drive, rate = Drive(f_l=0.2), 10000.0    # a load stuck by its friction: the motor alone breaks away
    ratio = 0.4
    level = drive.f_m * (1 + (static if static is not None else ratio))
    tau = np.concatenate([np.linspace(0.0, 1.0005 * level, 2001)[:-1], np.full(200, 1.0005 * level)])
    stribeck = Effects(stribeck=Stribeck(ratio, 1e-4, "exponential", static, bodies=("motor",)))
    _, rec = _run(drive, stribeck, tau, rate, d0_frac=0.0)
    first = int(np.argmax(tau > level))
    assert np.all(rec.q_m[:first + 1] == 0.0) and rec.q_m[first + 2] > 0.0
    coulomb = Drive(f_m=level, f_l=0.2)
    _, flat = _run(coulomb, Effects(), tau, rate, LinearEngine, d0_frac=0.0)
    assert rec.q_m[-1] > 100 * flat.q_m[-1] > 0.0


def test_kinematic_error_shows_two_and_four_per_rev_lines() -> None:
    """A slow move of ~2 motor revolutions on a stiff drive: the load angle minus r q_m, fitted by a smooth trend
    plus harmonics of the motor angle, has the 2/rev and 4/rev lines at the drawn amplitudes and phases (within
    1 %, 0.01 rad) and nothing at 1, 3, 6 /rev (< 0.5 % of the 2/rev line)."""
    kin = KinematicError(2e-5, 0.7, 6e-6, 2.1)
    drive, rate = Drive.from_nondim(1e7, 2500, 0.1), 5000.0
    n, ramp = int(0.5 * rate), int(0.05 * rate)
    tau = np.full(n, 1.3 * drive.f_m)
    tau[:ramp] *= np.arange(ramp) / ramp
    _, rec = _run(drive, Effects(kinematic_error=kin), tau, rate, d0_frac=0.0)
    t = np.arange(n + 1) / rate
    keep = t > 0.1
    q, y, tt = rec.q_m[keep], (rec.q_l - drive.r * rec.q_m)[keep], t[keep]
    orders = (1, 2, 3, 4, 6)
    A = np.column_stack([tt**p for p in range(4)] + [f(m * q) for m in orders for f in (np.sin, np.cos)])
    c = np.linalg.lstsq(A, y, rcond=None)[0][4:].reshape(-1, 2)
    amp = {m: math.hypot(*c[i]) for i, m in enumerate(orders)}
    phase = {m: math.atan2(c[i][1], c[i][0]) for i, m in enumerate(orders)}
    assert q[-1] - q[0] > 2 * math.pi
    assert amp[2] == pytest.approx(kin.amp2, rel=0.01) and amp[4] == pytest.approx(kin.amp4, rel=0.01)
    assert phase[2] == pytest.approx(kin.phase2, abs=0.01) and phase[4] == pytest.approx(kin.phase4, abs=0.01)
    assert max(amp[1], amp[3], amp[6]) < 0.005 * kin.amp2


# ------------------------------------------------------------------------------------ stick-slip, start ---------

@pytest.mark.parametrize("seed,kind", [(4105, "pd_steps"), (4110, "bidirectional"), (4102, "steps")])
def test_nothing_creeps_at_rest(seed: int, kind: str) -> None:
    """The start is at rest inside the static band: nothing moves over the 50 ms lead-in; later, whenever a
    sample shows both angles unchanged under an unchanged command, they stay bit-identical until it changes."""
    g = logs.identification_case(seed, kind, duration_s=1.5)
    lead = int(exc.LEAD_IN_S * g.sidecar["sample_rate_hz"])
    assert np.all(g.true_motor_pos_rad[:lead + 1] == g.true_motor_pos_rad[0])
    assert np.all(g.true_load_pos_rad[:lead + 1] == g.true_load_pos_rad[0])
    d = logs.draw_drive(seed)
    tau_s = d.K_s * g.truth.initial_deflection_rad
    assert abs(tau_s) <= 0.9 * d.f_l * (1 + 1e-12) and abs(d.r * tau_s) <= 0.9 * d.f_m * (1 + 1e-12)
    qm, ql, u = g.true_motor_pos_rad, g.true_load_pos_rad, g.motor_torque_Nm
    still = (np.diff(qm) == 0) & (np.diff(ql) == 0)
    rests = 0
    for k in np.flatnonzero(still[:-1]):
        if u[k + 1] == u[k]:      # same command after a step in which nothing moved: nothing can move
            assert qm[k + 2] == qm[k + 1] and ql[k + 2] == ql[k + 1]
            rests += 1
    assert rests > 100


# ------------------------------------------------------------------------------------ sensors, files ------------

def test_sensor_model() -> None:
    """Encoder: floor of the true angle in whole counts. Load sensor: true angle + offset + white noise whose
    standard deviation over ~40,000 samples is within 3 % of sigma (sampling spread ~0.4 %), mean at the offset."""
    g = logs.identification_case(4108, "steps", duration_s=4.0)
    count = 2 * math.pi / g.sidecar["encoder_counts_per_rev"]
    counts = g.motor_pos_rad / count
    assert np.all(np.abs(counts - np.round(counts)) < 1e-9)
    assert np.all((g.true_motor_pos_rad - g.motor_pos_rad >= -1e-12 * count)
                  & (g.true_motor_pos_rad - g.motor_pos_rad < count * (1 + 1e-9)))
    noise = g.load_pos_rad - g.true_load_pos_rad - g.truth.offset_rad
    sigma = g.truth.noise_sigma_rad
    assert sigma == pytest.approx(g.truth.noise_m / g.sidecar["arm_length_m"], rel=1e-12)
    assert noise.size > 30000 and np.std(noise) == pytest.approx(sigma, rel=0.03)
    assert abs(np.mean(noise)) < 5 * sigma / math.sqrt(noise.size)
    lag1 = np.corrcoef(noise[:-1], noise[1:])[0, 1]
    assert abs(lag1) < 5 / math.sqrt(noise.size)


@pytest.mark.parametrize("kind", exc.KINDS)
def test_written_files_read_back_with_the_product_reader(kind: str, tmp_path: Path) -> None:
    """Every excitation's log written in the product's format reads back exactly with ident.read_log."""
    g = logs.identification_case(4150 + exc.KINDS.index(kind), kind, duration_s=0.6)
    log = read_back(g, tmp_path)
    for name, column in g.columns().items():
        assert np.array_equal(getattr(log, name), column), name
    assert set(g.sidecar) == set(logs.SIDECAR_KEYS)
    assert log.meta.to_dict() == pytest.approx(g.sidecar)
    assert (tmp_path / "log.truth.json").is_file()
    assert list(g.to_frame().columns[:4]) == list(g.columns())
    if kind == "steps":
        assert g.plot(tmp_path / "log.png").stat().st_size > 0


def test_determinism_and_independent_streams(monkeypatch) -> None:
    """Same seed, same log, bit for bit; another seed, another drive; the drive does not depend on the
    excitation, and the measured columns do not repeat the truth. Made twice, not read from the store
    (``tests.reference.stored``), which relies on exactly this."""
    monkeypatch.setenv("HDRIVE_REFERENCE_CACHE", "0")
    a = logs.identification_case(4120, "chirp", duration_s=0.5)
    b = logs.identification_case(4120, "chirp", duration_s=0.5)
    for name, column in a.columns().items():
        assert np.array_equal(column, getattr(b, name))
    assert a.truth.to_dict() == b.truth.to_dict()
    c = logs.identification_case(4121, "chirp", duration_s=0.5)
    assert c.truth.K_star != a.truth.K_star
    d = logs.identification_case(4120, "steps", duration_s=0.5)
    assert d.truth.si == a.truth.si and d.truth.offset_rad == a.truth.offset_rad


def test_generator_imports_nothing_of_the_product() -> None:
    """Independence: importing and running the generator loads neither ident nor fmu_build."""
    code = ("import sys; from tests.reference.generator import identification_case as f; f(4101, 'steps', 0.2);"
            "bad = [m for m in sys.modules if m.split('.')[0] in ('ident', 'fmu_build')]; print(bad); "
            "sys.exit(1 if bad else 0)")
    root = Path(__file__).resolve().parents[1]
    done = subprocess.run([sys.executable, "-c", code], check=False, cwd=root, capture_output=True, text=True, timeout=120,
                          env={"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin"})
    assert done.returncode == 0, done.stdout + done.stderr


# ------------------------------------------------------------------------------------ excitations ---------------

def test_excitation_designs_within_their_ranges() -> None:
    """The drawn designs respect their documented ranges (in units of f_m, seconds)."""
    f_m, rate = 0.01, 5000.0
    rng = np.random.default_rng(77)
    pulse = exc.draw("pulse_train", rng, f_m, rate, 2.0)
    a, spacing = pulse.params["amplitude_star"], pulse.params["spacing_s"]
    assert 1.05 <= abs(a) <= 1.5 and 0.02 <= spacing <= 0.1
    on = np.flatnonzero(pulse.schedule)
    onsets = on[np.concatenate([[True], np.diff(on) > 1])]
    assert np.allclose(pulse.schedule[on], a * f_m) and np.all(np.diff(onsets) == round(spacing * rate))
    assert on.size == onsets.size * round(pulse.params["width_s"] * rate) and pulse.params["width_s"] == 1e-3
    steps = exc.draw("steps", rng, f_m, rate, 4.0).schedule / f_m
    levels = steps[steps != 0]
    assert np.all((np.abs(levels) >= 1.3) & (np.abs(levels) <= 3.0)) and (levels > 0).any() and (levels < 0).any()
    default = exc.draw("default", rng, f_m, rate, 4.0).schedule / f_m
    assert set(np.round(default[default != 0][np.abs(default[default != 0]) > 1.2], 6)) == {1.6, -1.6, 2.5, -2.5,
                                                                                             4.0, -4.0}
    assert np.max(np.abs(default[np.abs(default) <= 1.2])) == pytest.approx(1.15)
    chirp = exc.draw("chirp", rng, f_m, rate, 1.0)
    assert np.max(np.abs(chirp.schedule)) <= chirp.params["amplitude_star"] * f_m * (1 + 1e-12)


def test_closed_loop_log_is_the_pd_on_the_logged_encoder() -> None:
    """The pd_steps log keeps what the controller sent: recomputing the PD from the *logged* encoder column and
    the set-point steps of the truth reproduces the torque column exactly, saturation included."""
    g = logs.identification_case(4123, "pd_steps", duration_s=1.0)
    p, d = g.truth.excitation, logs.draw_drive(4123)
    dt, y = 1.0 / g.sidecar["sample_rate_hz"], g.motor_pos_rad
    count = 2 * math.pi / g.sidecar["encoder_counts_per_rev"]
    setpoint = np.full(y.size, y[0])
    for k, size in zip(p["setpoint_step_samples"], p["setpoint_steps_counts"]):
        setpoint[k:] += size * count
    rate = np.concatenate([[0.0], np.diff(y) / dt])
    u = d.f_m * (p["kp_star"] * (setpoint - y) - p["kd_star"] * d.T_c * rate)
    u = np.clip(u, -p["saturation_star"] * d.f_m, p["saturation_star"] * d.f_m)
    assert np.allclose(g.motor_torque_Nm, u, rtol=1e-12, atol=1e-15 * d.f_m)
    assert np.any(np.abs(g.motor_torque_Nm) == p["saturation_star"] * d.f_m)


# ------------------------------------------------------------------------------------ scenarios, suites ---------

def test_weak_medium_strong_classes() -> None:
    """weak: the effect's own signal is 5 sigma (search tolerance 15 %); medium and strong are sqrt(10) and 10
    times its magnitude; the recorded SNR rises with the class."""
    cases = {cls: logs.diagnosis_case(5101, "viscous_load", cls, "steps", duration_s=1.0) for cls in CLASSES}
    weak = cases["weak"].truth
    assert weak.snr["viscous_load"] == pytest.approx(WEAK_SNR, rel=SEARCH_TOLERANCE)
    for cls, factor in CLASSES.items():
        t = cases[cls].truth
        assert t.magnitudes["viscous_load"][0] == pytest.approx(factor * weak.magnitudes["viscous_load"][0])
        assert t.effects["b_l"] == t.magnitudes["viscous_load"][0]
    snrs = [cases[c].truth.snr["viscous_load"] for c in CLASSES]
    assert snrs == sorted(snrs) and snrs[-1] > 5 * snrs[0]


def test_two_effect_and_outside_library_cases() -> None:
    """Two-effect logs carry both effects, each with its own SNR; outside-library logs name an effect the
    product's library does not have."""
    two = logs.two_effect_case(5301, effects=("viscous_load", "asymmetric_friction"),
                               magnitude_classes=("medium", "strong"), duration_s=0.5)
    assert two.truth.effect_names == ["viscous_load", "asymmetric_friction"]
    assert set(two.truth.snr) == {"viscous_load", "asymmetric_friction"} and min(two.truth.snr.values()) > WEAK_SNR
    out = logs.outside_library_case(5401, "actuator_lag", "strong", duration_s=0.5)
    assert out.truth.effect_names == ["actuator_lag"] and out.truth.effects["actuator_lag_s"] > 0
    assert out.truth.snr["actuator_lag"] > 3 * WEAK_SNR
    assert out.truth.engine == "LinearEngine"


def test_suites() -> None:
    """Sizes the issues ask for; every excitation and library effect covered; no product seed (0-3)."""
    assert len(logs.IDENTIFICATION_SUITE) >= 12 and len(logs.IDENTIFICATION_SLOW_SUITE) >= 60
    assert {k for _, k in logs.IDENTIFICATION_SUITE} == set(logs.IDENTIFICATION_KINDS)
    assert len(logs.DIAGNOSIS_MATRIX) == len(LIBRARY_EFFECTS) * 3 * 3 * 2
    assert {(e, v) for _, e, _, _, v in logs.DIAGNOSIS_MATRIX if e in VARIANTS} == {
        (e, v) for e, vs in VARIANTS.items() for v in vs}
    assert len(logs.CLEAN_SUITE) == 20 and len(logs.TWO_EFFECT_SUITE_SEEDS) == 10
    assert len(logs.OUTSIDE_LIBRARY_SUITE) == 10
    seeds = ([s for s, _ in logs.IDENTIFICATION_SLOW_SUITE + logs.IDENTIFICATION_SUITE + logs.CLEAN_SUITE
              + logs.OUTSIDE_LIBRARY_SUITE] + [m[0] for m in logs.DIAGNOSIS_MATRIX] + logs.TWO_EFFECT_SUITE_SEEDS)
    assert not set(seeds) & {0, 1, 2, 3}


def test_bad_arguments_are_named() -> None:
    with pytest.raises(ValueError, match="unknown excitation 'ramp'"):
        logs.identification_case(4101, "ramp")
    with pytest.raises(ValueError, match="not a library effect"):
        logs.diagnosis_case(4101, "actuator_lag", "weak")
    with pytest.raises(ValueError, match="magnitude class 'huge'"):
        logs.diagnosis_case(4101, "viscous_load", "huge", duration_s=0.2)
    with pytest.raises(ValueError, match="variant 'quadratic'"):
        logs.diagnosis_case(4101, "hardening", "weak", variant="quadratic", duration_s=0.2)
    with pytest.raises(ValueError, match="breakaway level"):
        Stribeck(0.5, 1e-3, static_ratio=0.2)


@pytest.mark.slow
@pytest.mark.parametrize("effect,variant", [(e, v) for e in LIBRARY_EFFECTS for v in VARIANTS.get(e, (None,))]
                         + [("actuator_lag", None), ("friction_ripple", None)])
def test_every_effect_and_variant_reaches_its_classes(effect: str, variant: str | None) -> None:
    """Every effect and shape: the weak class at 5 sigma within the search tolerance (or its physical cap),
    strong well above it, on a 4 s log of the default design."""
    make = logs.diagnosis_case if effect in LIBRARY_EFFECTS else logs.outside_library_case
    kw = {"variant": variant} if effect in LIBRARY_EFFECTS else {}
    weak, strong = (make(5102, effect, cls, "default", **kw) for cls in ("weak", "strong"))
    if "capped" not in weak.truth.magnitude_classes[effect]:
        assert weak.truth.snr[effect] == pytest.approx(WEAK_SNR, rel=SEARCH_TOLERANCE)
    assert strong.truth.snr[effect] > 3 * weak.truth.snr[effect]


def test_smallest_sigma_constant() -> None:
    """The accuracy budget above is derived from the smallest noise the generator draws."""
    assert SMALLEST_SIGMA_RAD == pytest.approx(1e-9 / 0.5)
    assert min(logs.draw_rate_and_sensors(s)[1].noise_m for s in range(4100, 4300)) >= 1e-9
