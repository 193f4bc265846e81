"""Independent, event-driven reference simulator of the HarmonicDrive plant (SI units).

This is the accuracy yardstick for the C FMU. It deliberately shares nothing with the C model: instead of
closed-form segments it integrates the equations numerically with ``scipy.integrate.solve_ivp`` (DOP853,
rtol = 1e-12) and locates every Karnopp switching event with solve_ivp's event root finder.

    J_m q_m'' = T - F_m - r K_s d          d = r q_m - q_l   (spring deflection, load-side rad)
    J_l q_l'' = K_s d - F_l

Each body is in one of three modes: stuck (velocity exactly 0), or slipping in direction +1 / -1 (friction
-dir * f, constant while the mode lasts). A body with zero friction level never sticks. Within a mode the
equations are linear with constant forcing; a segment ends at the first event:

* a slipping body's velocity reaches zero (only the crossing *towards* the opposite sign counts; for a
  slip that starts from v = 0 the event function is v / tau, so that tau = 0 is never mistaken for a root);
* a stuck body's net non-friction torque N (motor: T - r K_s d, load: K_s d) crosses +f upwards or -f
  downwards.

At a zero-velocity event the body sticks if |N| <= f, else slips in direction sign(N). At a breakaway event
the direction is taken from *which* threshold was crossed, not from re-evaluating |N| > f, because at the
located root |N| equals f to round-off and re-evaluating would make the body stick again (a Zeno loop).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np
from scipy.integrate import solve_ivp

from .stored import stored

RTOL = 1e-12
# atol relative to the natural scale of each state component (see _atol): 100x tighter than rtol, yet
# ~50x above the round-off floor.
ATOL_REL = 1e-14
# Events per call before declaring a Zeno loop (a real pulse-to-rest needs a few dozen).
MAX_EVENTS = 100_000

MOTOR, LOAD = 0, 1
STUCK = 0  # mode value of a stuck body; slipping bodies carry their direction +1 / -1

Mode = tuple[int, int]


@dataclass
class DriveSI:
    """Plant parameters in SI units (kg m^2, N m, N m/rad, m)."""

    J_m: float
    f_m: float
    K_s: float
    J_l: float
    f_l: float
    r: float
    arm_length: float

    @classmethod
    def nominal(cls) -> DriveSI:
        """The nominal drive of physics.md section 2 (f_l* = 0.1, K* = 1e6, J_l* = 2500)."""
        return cls(J_m=2e-5, f_m=0.01, K_s=1e4, J_l=0.05, f_l=1e-3, r=0.01, arm_length=0.3)

    @classmethod
    def from_nondim(cls, K_star: float, J_l_star: float, f_l_star: float, J_m: float = 2e-5,
                    f_m: float = 0.01, r: float = 0.01, arm_length: float = 0.3) -> DriveSI:
        """Drive from the paper's non-dimensional groups K* = K_s/f_m, J_l* = J_l/J_m, f_l* = f_l/f_m."""
        return cls(J_m=J_m, f_m=f_m, K_s=K_star * f_m, J_l=J_l_star * J_m, f_l=f_l_star * f_m, r=r,
                   arm_length=arm_length)

    @property
    def T_c(self) -> float:
        """Characteristic time sqrt(J_m / f_m) [s] of the non-dimensional form."""
        return math.sqrt(self.J_m / self.f_m)

    @property
    def omega(self) -> float:
        """Ringing frequency [rad/s] of the spring with both bodies slipping."""
        return math.sqrt(self.K_s * (self.r**2 / self.J_m + 1.0 / self.J_l))

    def frictions(self) -> tuple[float, float]:
        return self.f_m, self.f_l


@dataclass
class State:
    """Plant state. The default is the protocol start: at rest, zero deflection, both bodies stuck.

    A stuck body's velocity is taken as exactly zero. ``input_work`` (sum of T * dq_m per constant-torque
    piece) and ``friction_work`` (sum of f * |dq| per slip segment) accumulate from the start, in J.
    """

    q_m: float = 0.0
    q_l: float = 0.0
    v_m: float = 0.0
    v_l: float = 0.0
    motor_stuck: bool = True
    load_stuck: bool = True
    time: float = 0.0
    input_work: float = 0.0
    friction_work: float = 0.0

    def deflection(self, drive: DriveSI) -> float:
        """Spring deflection d = r q_m - q_l [rad, load side]."""
        return drive.r * self.q_m - self.q_l


class Trajectory(NamedTuple):
    """Samples of a constant-torque run (arrays of equal length)."""

    t: np.ndarray
    q_m: np.ndarray
    q_l: np.ndarray
    v_m: np.ndarray
    v_l: np.ndarray


@dataclass(frozen=True)
class _Event:
    body: int
    kind: str  # "stop" (velocity reached zero), "break_up" (N crossed +f), "break_down" (N crossed -f)


# ---------------------------------------------------------------------------------------------------------
# Mode logic (Karnopp)


def _net_torques(drive: DriveSI, q_m: float, q_l: float, torque: float) -> tuple[float, float]:
    """Net non-friction torques (N_m, N_l) on the motor and the load."""
    spring = drive.K_s * (drive.r * q_m - q_l)
    return torque - drive.r * spring, spring


def _decide_at_rest(net: float, level: float) -> int:
    """Mode of a body at zero velocity: stuck unless |N| exceeds the static level, then slip along N."""
    if level == 0.0:
        return 1  # frictionless: never stuck; the direction only multiplies a zero friction torque
    if abs(net) <= level:
        return STUCK
    return 1 if net > 0.0 else -1


def _with_mode(state: State, mode: Mode) -> State:
    """Stuck flags from the mode; a stuck body's velocity is exactly zero."""
    return replace(state, motor_stuck=mode[MOTOR] == STUCK, load_stuck=mode[LOAD] == STUCK,
                   v_m=0.0 if mode[MOTOR] == STUCK else state.v_m,
                   v_l=0.0 if mode[LOAD] == STUCK else state.v_l)


def _initial_mode(drive: DriveSI, state: State, torque: float) -> tuple[State, Mode]:
    """Mode at the start of a constant-torque piece (the torque may just have changed)."""
    nets = _net_torques(drive, state.q_m, state.q_l, torque)
    stuck = (state.motor_stuck, state.load_stuck)
    vels = (state.v_m, state.v_l)
    mode = []
    for body, level in enumerate(drive.frictions()):
        if level == 0.0:
            mode.append(1)
        elif stuck[body] or vels[body] == 0.0:
            mode.append(_decide_at_rest(nets[body], level))
        else:
            mode.append(1 if vels[body] > 0.0 else -1)
    return _with_mode(state, (mode[0], mode[1])), (mode[0], mode[1])


def _after_event(drive: DriveSI, state: State, mode: Mode, event: _Event,
                 torque: float) -> tuple[State, Mode]:
    """Karnopp transition at ``event``; also catches an event of the other body hidden in the same step
    (solve_ivp reports only the first terminal event of a step)."""
    nets = _net_torques(drive, state.q_m, state.q_l, torque)
    vels = [state.v_m, state.v_l]
    new = list(mode)
    for body, level in enumerate(drive.frictions()):
        if level == 0.0:
            continue
        if body == event.body and event.kind == "stop":
            vels[body] = 0.0
            new[body] = _decide_at_rest(nets[body], level)
        elif body == event.body:  # trust the crossed threshold, see the module docstring
            new[body] = 1 if event.kind == "break_up" else -1
        elif mode[body] == STUCK and abs(nets[body]) > level:
            new[body] = 1 if nets[body] > 0.0 else -1
        elif mode[body] != STUCK and vels[body] * mode[body] < 0.0:
            vels[body] = 0.0
            new[body] = _decide_at_rest(nets[body], level)
    mode = (new[0], new[1])
    return _with_mode(replace(state, v_m=vels[0], v_l=vels[1]), mode), mode


# ---------------------------------------------------------------------------------------------------------
# One segment: fixed mode, constant torque, until the first event or the end of the piece


def _linear_system(drive: DriveSI, state: State, mode: Mode, torque: float) -> tuple[np.ndarray, np.ndarray]:
    """y' = A y + b for y = (q_m - q_m0, q_l - q_l0, v_m, v_l).

    Positions are integrated relative to the segment start so that rtol applies to the motion of this
    segment, not to the (possibly large) absolute angles: the deflection d is a small difference of them.
    """
    r, K = drive.r, drive.K_s
    d0 = state.deflection(drive)
    A = np.zeros((4, 4))
    b = np.zeros(4)
    if mode[MOTOR] != STUCK:
        A[0, 2] = 1.0
        A[2, 0], A[2, 1] = -r * r * K / drive.J_m, r * K / drive.J_m
        b[2] = (torque - mode[MOTOR] * drive.f_m - r * K * d0) / drive.J_m
    if mode[LOAD] != STUCK:
        A[1, 3] = 1.0
        A[3, 0], A[3, 1] = r * K / drive.J_l, -K / drive.J_l
        b[3] = (K * d0 - mode[LOAD] * drive.f_l) / drive.J_l
    return A, b


def _atol(drive: DriveSI, state: State, torque: float, span: float) -> np.ndarray:
    """Absolute tolerances for y = (dq_m, dq_l, v_m, v_l), from a motor-side velocity scale V.

    atol must sit above the round-off floor of each component (about eps * its largest value in the
    segment), else the step size collapses where a velocity passes through zero while rtol * |v| -> 0.
    V bounds the velocities of the segment: the current ones, what the torque can add over the span
    (friction only ever slows a body down) and the ringing speed a typical torque excites.
    """
    r, omega = drive.r, drive.omega
    torque_scale = max(drive.f_m, r * drive.f_l, abs(torque), r * drive.K_s * abs(state.deflection(drive)))
    v_scale = (abs(state.v_m) + abs(state.v_l) / r + abs(torque) * span / drive.J_m
               + torque_scale / (drive.J_m * omega))
    if v_scale == 0.0:
        v_scale = 1.0  # nothing can move at all; any positive tolerance will do
    return ATOL_REL * v_scale * np.array([1.0 / omega, r / omega, 1.0, r])


def _event_functions(drive: DriveSI, state: State, mode: Mode,
                     torque: float) -> tuple[list[Callable], list[_Event]]:
    """Terminal, direction-aware event functions of this mode, with what each one means."""
    r, K = drive.r, drive.K_s
    d0 = state.deflection(drive)

    def net(body: int) -> Callable[[np.ndarray], float]:
        if body == MOTOR:
            return lambda y: torque - r * K * (d0 + r * y[0] - y[1])
        return lambda y: K * (d0 + r * y[0] - y[1])

    funcs: list[Callable] = []
    events: list[_Event] = []

    def add(g: Callable[[float, np.ndarray], float], direction: float, event: _Event) -> None:
        def fn(t: float, y: np.ndarray) -> float:
            return g(t, y)
        fn.terminal = True  # type: ignore[attr-defined]
        fn.direction = direction  # type: ignore[attr-defined]
        funcs.append(fn)
        events.append(event)

    inertias = (drive.J_m, drive.J_l)
    velocities = (state.v_m, state.v_l)
    for body, level in enumerate(drive.frictions()):
        if level == 0.0:
            continue
        n = net(body)
        if mode[body] == STUCK:
            add(lambda _t, y, n=n, f=level: n(y) - f, 1.0, _Event(body, "break_up"))
            add(lambda _t, y, n=n, f=level: n(y) + f, -1.0, _Event(body, "break_down"))
        elif velocities[body] != 0.0:
            add(lambda _t, y, i=2 + body: y[i], -float(mode[body]), _Event(body, "stop"))
        else:
            # Slip starting from v = 0: v itself is zero at tau = 0, and when the slip is a micro-slip that
            # returns to v = 0 inside the first step, the root finder would return tau = 0 again and again.
            # v / tau has the same later roots, and at tau = 0 the value of the initial acceleration.
            a0 = (n(np.zeros(4)) - mode[body] * level) / inertias[body]
            add(lambda t, y, i=2 + body, a0=a0: y[i] / t if t > 0.0 else a0, -float(mode[body]),
                _Event(body, "stop"))
    return funcs, events


def _segment(drive: DriveSI, state: State, mode: Mode, torque: float,
             span: float) -> tuple[State, _Event | None]:
    """Integrate one fixed-mode segment for at most ``span`` seconds; return the end state and its event."""
    A, b = _linear_system(drive, state, mode, torque)
    funcs, events = _event_functions(drive, state, mode, torque)
    y0 = np.array([0.0, 0.0, state.v_m, state.v_l])
    sol = solve_ivp(lambda _t, y: A @ y + b, (0.0, span), y0, method="DOP853", rtol=RTOL,
                    atol=_atol(drive, state, torque, span), events=funcs)
    if sol.status < 0:
        raise RuntimeError(f"solve_ivp failed: {sol.message}")
    fired = None
    tau, y = sol.t[-1], sol.y[:, -1]
    if sol.status == 1:
        k = min((k for k, te in enumerate(sol.t_events) if te.size), key=lambda k: sol.t_events[k][0])
        fired, tau, y = events[k], sol.t_events[k][0], sol.y_events[k][0]
    dq_m, dq_l, v_m, v_l = (float(x) for x in y)
    # A slipping body's friction opposes its fixed direction, so it dissipates f * dir * dq (stuck: dir = 0).
    friction_work = drive.f_m * mode[MOTOR] * dq_m + drive.f_l * mode[LOAD] * dq_l
    end = replace(state, q_m=state.q_m + dq_m, q_l=state.q_l + dq_l, v_m=v_m, v_l=v_l,
                  time=state.time + float(tau), input_work=state.input_work + torque * dq_m,
                  friction_work=state.friction_work + friction_work)
    return end, fired


# ---------------------------------------------------------------------------------------------------------
# Public API


def _advance(drive: DriveSI, state: State, torque: float, duration: float, stop_at_rest: bool) -> State:
    """Hold ``torque`` for ``duration`` s, or (``stop_at_rest``) until both bodies are stuck."""
    if duration < 0.0:
        raise ValueError("duration must be non-negative")
    t_end = state.time + duration
    state, mode = _initial_mode(drive, state, torque)
    for _ in range(MAX_EVENTS):
        if mode == (STUCK, STUCK):
            # Nothing moves and N is constant while T is: no event can happen before the torque changes.
            return state if stop_at_rest else replace(state, time=t_end)
        span = t_end - state.time
        if span <= 0.0:
            return replace(state, time=t_end)
        state, event = _segment(drive, state, mode, torque, span)
        if event is None:
            return replace(state, time=t_end)
        state, mode = _after_event(drive, state, mode, event, torque)
    raise RuntimeError(f"more than {MAX_EVENTS} events in one call (Zeno behaviour?)")


def simulate(drive: DriveSI, state: State, torque: float, duration: float) -> State:
    """Hold motor torque ``torque`` [N m] for ``duration`` [s] from ``state``; return the state at the end."""
    return _advance(drive, state, torque, duration, stop_at_rest=False)


def run_to_rest(drive: DriveSI, state: State, max_time: float = 10.0) -> State:
    """Zero torque until both bodies are stuck; return the state at that moment.

    Raises RuntimeError if the drive is not at rest within ``max_time`` seconds (a frictionless body
    never sticks, so such a drive never comes to rest).
    """
    end = _advance(drive, state, 0.0, max_time, stop_at_rest=True)
    if not (end.motor_stuck and end.load_stuck):
        raise RuntimeError(f"drive not at rest after {max_time} s")
    return end


@stored
def pulse_increments(drive: DriveSI, amplitude_star: float, width_star: float, n_pulses: int,
                     state: State | None = None) -> tuple[list[float], State]:
    """Impulse protocol (physics.md section 3): ``n_pulses`` pulses, each T = A f_m for W = W* T_c, then rest.

    Returns the load increments at the arm tip [m] (change of q_l between rests times arm_length) and the
    final state. The state carries over between pulses; a start state not at rest is first brought to rest.
    """
    state = State() if state is None else state
    if not (state.motor_stuck and state.load_stuck):
        state = run_to_rest(drive, state)
    torque, width = amplitude_star * drive.f_m, width_star * drive.T_c
    increments = []
    for _ in range(n_pulses):
        q_l_before = state.q_l
        state = run_to_rest(drive, simulate(drive, state, torque, width))
        increments.append((state.q_l - q_l_before) * drive.arm_length)
    return increments, state


def trajectory(drive: DriveSI, state: State, torque: float, duration: float, n_points: int) -> Trajectory:
    """``n_points`` equally spaced samples (both ends included) of a constant-torque run, for plots.

    Each interval between samples is an exact ``simulate`` call, so sampling does not perturb the events.
    """
    times = state.time + np.linspace(0.0, duration, n_points)
    rows = []
    for t in times:
        state = simulate(drive, state, torque, t - state.time)
        rows.append((state.q_m, state.q_l, state.v_m, state.v_l))
    q_m, q_l, v_m, v_l = np.array(rows).T
    return Trajectory(times, q_m, q_l, v_m, v_l)
