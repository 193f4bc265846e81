"""Integrators of the hybrid plant (``plant.HybridPlant``) over a log's sample grid, with located mode changes.

The command is held over each sample interval ([t_k, t_k+1)). Within one interval the mode changes at the zeros of
its guards; both engines find the *first* zero of any guard, stop there, let the plant apply the Karnopp
transition and go on. A mode in which nothing can move (both bodies stuck, no lag transient) is skipped in O(1).

* ``LinearEngine`` -- for effects whose modes are linear with constant forcing (the base model, viscous and
  asymmetric friction, the three-slope spring, Maxwell-slip hysteresis, actuator lag). Per mode the affine system
  z' = M z, z = [x, T_cmd, 1], is read off the plant's own right-hand side, propagated by the matrix exponential,
  and each guard along the interval is the power series sum_k (E M^k z0 / k!) tau^k, whose first zero is found
  rigorously: a grid plus the Taylor bound on the dip between grid points, then Newton on the polynomial.
* ``RKEngine`` -- for everything (Stribeck, cubic spring, Dahl, kinematic error, friction ripple): adaptive
  Dormand-Prince 8(5,3) steps in plain Python floats, guards checked at every step end and for a dip inside the
  step (cubic Hermite of guard values and rates), zeros located by a safeguarded secant on exact re-steps.

Both are checked against the independent ``tests/reference/event_driven.py`` (base model) and against each other
(piecewise-linear effects) in ``tests/test_reference_logs.py``.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy.integrate import DOP853
from scipy.optimize import brentq

from .plant import Guard, HybridPlant, Mode, Vector

MAX_EVENTS_PER_SAMPLE = 2000
FRESH_TOL = 1e-9          # a guard within FRESH_TOL * scale of zero at a segment start has just been switched on


class Engine(Protocol):
    def propagate(self, x: Vector, u: float, mode: Mode, span: float) -> tuple[Vector, float, Guard | None]:
        """Advance ``x`` in ``mode`` under command ``u`` for at most ``span`` s; stop at the first guard zero.
        Returns (state, time advanced, the guard that fired or None)."""


@dataclass
class SampleRecord:
    """True trajectory at the sample instants (length n + 1)."""

    q_m: np.ndarray
    q_l: np.ndarray
    states: np.ndarray | None = None
    events: int = 0


def advance(plant: HybridPlant, engine: Engine, x: Vector, mode: Mode, u: float, dt: float) -> tuple[Vector, Mode,
                                                                                                      int]:
    """Hold command ``u`` for ``dt`` s from (x, mode); return the new (x, mode) and the number of mode changes."""
    x, mode = plant.settle(x, u, mode)
    t, events = 0.0, 0
    while events < MAX_EVENTS_PER_SAMPLE:
        if plant.frozen(x, u, mode) or dt - t <= 0.0:
            return x, mode, events
        x, tau, guard = engine.propagate(x, u, mode, dt - t)
        t += tau
        if guard is None:
            return x, mode, events
        x, mode = plant.transition(x, u, mode, guard)
        x, mode = plant.settle(x, u, mode)
        events += 1
    raise RuntimeError(f"more than {MAX_EVENTS_PER_SAMPLE} mode changes in one sample (Zeno behaviour?)")


def simulate(plant: HybridPlant, engine: Engine, x: Vector, mode: Mode, dt: float,
             command: Callable[[int, float], float], n: int, keep_states: bool = False) -> tuple[SampleRecord,
                                                                                                  np.ndarray]:
    """Run ``n`` sample intervals of ``dt``; ``command(k, q_m_k)`` gives the command held over interval k from the
    true motor angle at t_k (a controller measures it itself). Returns the record and the commands (length n)."""
    prepare = getattr(engine, "prepare", None)
    if prepare is not None:
        prepare(dt)
    q_m, q_l = np.empty(n + 1), np.empty(n + 1)
    states = np.empty((n + 1, plant.n_states)) if keep_states else None
    commands = np.empty(n)
    events = 0
    for k in range(n + 1):
        q_m[k] = x[0]
        q_l[k] = x[1]
        if states is not None:
            states[k] = x
        if k == n:
            break
        u = commands[k] = command(k, x[0])
        x, mode, e = advance(plant, engine, x, mode, u, dt)
        events += e
    return SampleRecord(q_m, q_l, states, events), commands


# ----------------------------------------------------------------------------------------- Runge-Kutta ---------

def _tableau() -> tuple[list[list[tuple[int, float]]], list[tuple[int, float]], list[float], list[float],
                        list[float]]:
    """DOP853's coefficients (scipy's public class attributes), as sparse rows for plain-float stages."""
    rows = [[(i, float(a)) for i, a in enumerate(DOP853.A[s, :s]) if a != 0.0] for s in range(DOP853.n_stages)]
    b = [(i, float(v)) for i, v in enumerate(DOP853.B) if v != 0.0]
    return rows, b, DOP853.C.tolist(), DOP853.E3.tolist(), DOP853.E5.tolist()


_ROWS, _B, _C, _E3, _E5 = _tableau()
_STEP_CACHE: dict[int, Callable] = {}


def _step_function(n: int) -> Callable:
    """A DOP853 step for states of length ``n``, unrolled into straight-line code (3-4x faster than loops in
    CPython). ``step(rhs, x, u, f0, h) -> (x1, f1, e5, e3)``: the 8th-order result, the slope there, and the
    unscaled 5th- and 3rd-order error estimates."""
    fn = _STEP_CACHE.get(n)
    if fn is not None:
        return fn
    comps = range(n)
    lines = ["def step(rhs, x, u, f0, h):", f"    {', '.join(f'x{j}' for j in comps)}, = x",
             f"    {', '.join(f'k0_{j}' for j in comps)}, = f0"]
    for st in range(1, 12):
        args = ", ".join(f"x{j} + h * ({' + '.join(f'{a!r} * k{i}_{j}' for i, a in _ROWS[st])})" for j in comps)
        lines.append(f"    {', '.join(f'k{st}_{j}' for j in comps)}, = rhs([{args}], u)")
    out = ", ".join(f"x{j} + h * ({' + '.join(f'{b!r} * k{i}_{j}' for i, b in _B)})" for j in comps)
    lines += [f"    x1 = [{out}]", "    f1 = rhs(x1, u)", f"    {', '.join(f'k12_{j}' for j in comps)}, = f1"]
    for name, coef in (("e5", _E5), ("e3", _E3)):
        terms = [(i, c) for i, c in enumerate(coef) if c != 0.0]
        vec = ", ".join(" + ".join(f"{c!r} * k{i}_{j}" for i, c in terms) for j in comps)
        lines.append(f"    {name} = [{vec}]")
    lines.append("    return x1, f1, e5, e3")
    namespace: dict = {}
    exec(compile("\n".join(lines), f"<dop853 step, n={n}>", "exec"), namespace)  # noqa: S102 (generated above)
    fn = _STEP_CACHE[n] = namespace["step"]
    return fn


@dataclass
class RKEngine:
    """Adaptive DOP853 in plain floats (see the module docstring). ``rtol`` sets the local error relative to the
    plant's deflection / speed scales (absolute for angles, so that the deflection, a small difference of two
    angles, keeps its precision)."""

    plant: HybridPlant
    rtol: float = 1e-10
    h: float = 0.0
    steps: int = 0
    atol: list[float] = field(default_factory=list)
    relative: list[bool] = field(default_factory=list)

    def __post_init__(self) -> None:
        p, d = self.plant, self.plant.drive
        w = d.omega_max
        ds = p.d_scale
        scales = [ds / d.r, ds, ds * w / d.r, ds * w] + [math.inf] * (p.n_states - 4)
        if p.i_lag >= 0:
            scales[p.i_lag] = d.f_m
        if p.i_z >= 0:
            scales[p.i_z] = p.effects.hysteresis.torque
        for i in range(p.n_elements):
            scales[p.i_w + i] = p.effects.hysteresis.break_torques[i]
        self.atol = [self.rtol * s for s in scales]
        self.relative = [False, False] + [True] * (p.n_states - 2)
        if not self.h:
            self.h = 0.2 / w

    def step(self, rhs: Callable[[Vector, float], Vector], x: Vector, u: float, f0: Vector,
             h: float) -> tuple[Vector, Vector, float]:
        """One DOP853 step of size h: (new state, its slope, error norm in units of the tolerance)."""
        x1, f1, e5, e3 = _step_function(len(x))(rhs, x, u, f0, h)
        s5 = s3 = 0.0
        for j, (a5, a3) in enumerate(zip(e5, e3)):
            scale = self.atol[j] + (self.rtol * max(abs(x[j]), abs(x1[j])) if self.relative[j] else 0.0)
            if scale != math.inf:
                s5 += (a5 / scale) ** 2
                s3 += (a3 / scale) ** 2
        if s5 == 0.0 and s3 == 0.0:
            return x1, f1, 0.0
        return x1, f1, abs(h) * s5 / math.sqrt((s5 + 0.01 * s3) * len(x))

    def propagate(self, x: Vector, u: float, mode: Mode, span: float) -> tuple[Vector, float, Guard | None]:
        rhs = self.plant.rhs_for(mode)
        labels, gfun = self.plant.guards_for(mode)
        g0 = gfun(x, u)
        fresh = [abs(v) <= FRESH_TOL * lab.scale for v, lab in zip(g0, labels)]
        f0 = rhs(x, u)
        gd0 = _guard_rates(gfun, x, u, f0, self.h)
        t = 0.0
        while t < span:
            h = min(self.h, span - t)
            x1, f1, err = self.step(rhs, x, u, f0, h)
            if err > 1.0:
                self.h = h * max(0.2, 0.9 * err ** (-1.0 / 8.0))
                continue
            self.steps += 1
            g1 = gfun(x1, u)
            gd1 = _guard_rates(gfun, x1, u, f1, h)
            hit = _first_zero(self, rhs, gfun, labels, x, u, f0, h, (g0, gd0, g1, gd1), fresh)
            h_new = h * min(5.0, 0.9 * err ** (-1.0 / 8.0)) if err > 0.0 else 5.0 * h
            self.h = h_new if h >= self.h else max(self.h, h_new)  # a step cut short by the span keeps self.h
            if hit is not None:
                xe, tau, guard = hit
                return xe, t + tau, guard
            x, f0, g0, gd0, t = x1, f1, g1, gd1, t + h
            fresh = [False] * len(fresh)
        return x, span, None


def _guard_rates(gfun: Callable[[Vector, float], Vector], x: Vector, u: float, f: Vector, h: float) -> Vector:
    """d/dt of every guard along x' = f (central difference along the tangent; exact for affine guards)."""
    eps = 1e-4 * h
    plus = gfun([a + eps * b for a, b in zip(x, f)], u)
    minus = gfun([a - eps * b for a, b in zip(x, f)], u)
    return [(p - m) / (2.0 * eps) for p, m in zip(plus, minus)]


def _candidates(values: tuple[Vector, Vector, Vector, Vector], fresh: list[bool], h: float) -> list[tuple[int,
                                                                                                          float]]:
    """Guards that reach zero in (0, h]: (index, a time by which they are negative) -- a sign change at the
    end, or a dip below zero of the cubic Hermite interpolant of values and rates."""
    g0, gd0, g1, gd1 = values
    out = []
    for j, (a, da, b, db) in enumerate(zip(g0, gd0, g1, gd1)):
        if b < 0.0 and (a > 0.0 or fresh[j]):
            out.append((j, h))
        elif b >= 0.0 and (a > 0.0 or fresh[j]) and da < 0.0 < db:
            tmin, vmin = _hermite_min(a, da * h, b, db * h)
            if vmin < 0.0:
                out.append((j, tmin * h))
    return out


def _hermite_min(a: float, da: float, b: float, db: float) -> tuple[float, float]:
    """(s, value) at the interior minimum of the cubic Hermite on [0, 1] with end values a, b and slopes da, db."""
    lo, hi = 0.0, 1.0
    for _ in range(60):  # bisection on the slope, which goes from negative to positive
        s = 0.5 * (lo + hi)
        slope = (6 * s * s - 6 * s) * a + (3 * s * s - 4 * s + 1) * da + (6 * s - 6 * s * s) * b + (3 * s * s - 2 * s) * db
        lo, hi = (s, hi) if slope < 0.0 else (lo, s)
    s = 0.5 * (lo + hi)
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return s, h00 * a + h10 * da + h01 * b + h11 * db


def _first_zero(engine: RKEngine, rhs: Callable, gfun: Callable, labels: list[Guard], x: Vector, u: float,
                f0: Vector, h: float, values: tuple, fresh: list[bool]) -> tuple[Vector, float, Guard] | None:
    """Locate the first zero in (0, h] of the guards that may cross in this step (None if none does)."""
    cands = _candidates(values, fresh, h)
    if not cands:
        return None
    idx = [j for j, _ in cands]
    hi = min(t for _, t in cands)

    def worst(tau: float) -> tuple[float, Vector, int]:
        xt = _step_function(len(x))(rhs, x, u, f0, tau)[0]
        g = gfun(xt, u)
        j = min(idx, key=lambda i: g[i] / labels[i].scale)
        return g[j] / labels[j].scale, xt, j

    v_hi, x_hi, j_hi = worst(hi)
    if v_hi >= 0.0:
        return None  # a Hermite dip that the exact trajectory does not make
    lo = 0.0
    if any(fresh[j] for j in idx):  # a guard that starts at zero: find a time where all are positive again
        lo = hi
        for _ in range(40):
            lo *= 0.25
            v, xt, j = worst(lo)
            if v > 0.0:
                break
            hi, x_hi, j_hi = lo, xt, j
        else:  # negative at once: a direction assumed at dd = 0 (Dahl, Maxwell) is the wrong one; switch now
            return x, 0.0, labels[j_hi]
    last: dict = {}

    def value(tau: float) -> float:
        v, xt, j = worst(tau)
        if v < 0.0 and tau <= last.get("tau", math.inf):
            last.update(tau=tau, x=xt, j=j)
        return v

    last.update(tau=hi, x=x_hi, j=j_hi)
    root = brentq(value, lo, hi, xtol=1e-13 * h, rtol=4 * np.finfo(float).eps)
    if value(root) >= 0.0:  # brentq returns either side of the zero; the event state must have crossed it
        value(min(hi, root + 1e-13 * h))
    return last["x"], last["tau"], labels[last["j"]]
