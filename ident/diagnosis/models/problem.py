"""Output-error residuals of the two-inertia FMU with library effects switched on (the diagnosis's fits).

Unknowns: ``[ln K*, ln J_l*, ln f_l*, d0/band]`` (as ``ident.fitting.identify``) followed by each effect's
coordinates (``coordinates.coordinates``); ``fixed`` FMU parameters are held (the screen's columns), and ``general``
simulates through the FMU's general propagator with the same physics (``same_propagator``: the screen's).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial
from typing import Any

import numpy as np

from ...fitting.identify import EvaluationBudget, OutputError
from ...fitting.logs import DriveLog
from ...fitting.result import BASE_UNKNOWNS
from ...model.params import DriveParams
from ...model.pool import pooled_plant
from .coordinates import Coord, LogScales, coordinates, fmu_values

#: switches the FMU's general (Runge-Kutta) propagator on without changing the physics (``same_propagator``): the
#: viscous asymmetry only scales a viscous coefficient, and it is set only where there is none. The screen compares a
#: candidate's simulation with the current model's through the same propagator, so that the difference is the
#: effect's alone.
SAME_PROPAGATOR = {"viscous_asymmetry": 0.5}


def same_propagator(p: DriveParams) -> DriveParams:
    """``p`` through the FMU's general propagator with the same physics: where a viscous coefficient is on, the
    general propagator is on already and ``p`` is returned as it is (a viscous asymmetry would then change the
    friction: b (1 + a_v) one way, b (1 - a_v) the other); where none is, ``SAME_PROPAGATOR`` is set.

    Measured before this rule, when the switch was set on every screen: at a model with a viscous friction the
    current model's own residual was that of a 50 % asymmetric viscous term, every candidate passed the screen at
    statistics of 580-9300 on single-effect logs at 0.998x the noise, and their refits removed under 0.4 noise
    variances each."""
    if p.b_m != 0.0 or p.b_l != 0.0 or p.viscous_asymmetry != 0.0:
        return p
    return p.with_values(**SAME_PROPAGATOR)


#: the finite-difference step of an effect's coordinates (x ~ 1: an effect the log shows plainly,
#: ``coordinates``). Why not the 1e-6 of the initial deflection: a simulation's accumulated round-off (measured as the
#: second difference of the load angle over equal parameter steps: 4e-14 rad rms over a 3 s log at 5 kHz, 5e-6 of its
#: load noise, the same for either propagator) divided by a 1e-6 step made a coordinate's column 3.5x its size (a
#: viscous load coefficient: norm 357 against 102 with steps across the noise's scale, correlation 0.72; the kinematic
#: error's four: 0.96-0.99), and the refits' Gauss-Newton steps along it that much too short. At 1e-3 the column
#: is the one across the noise's scale to 0.1 % (1e-5: 8 %, 1e-4: 1.4 %), and the method's own error (h^2 times the
#: third derivative, on a coordinate whose unit is a plain effect) is far below it. Measured through the loop on the
#: generator's 10 s logs (bench/README.md, stop 72): the viscous-load and kinematic-error torque-step logs' intervals
#: hold the truth on 20 of 20 (with 1e-6, five noise draws of one viscous log: 0 of 5), six names right and tentative
#: before are confident, a false asymmetric friction is gone and that log takes 63 s instead of 221 s; the quick sample
#: names the same.
COORD_STEP = 1e-3

#: a fit stalls when its best cost has not fallen by more than this (relative) over ``stall_after`` simulations: the
#: cost of an exact stick-slip model has kinks where a marginal event flips, and IPOPT's line search can spend a
#: dozen simulations per iteration on one (measured: 13 per iteration, 100 of a refit's 300)
STALL_TOL = 1e-8

#: a fit is settled when the Gauss-Newton step at (a point within this of) its best point would lower the cost by
#: less than this many noise variances (``identify.gauss_newton_decrement``): that is the step's squared length in
#: the fit's own standard errors, so the optimum of the linear model is within a tenth of a standard error of the
#: point along every direction, and no comparison of costs can change by more than this. Why a stop on it: IPOPT's
#: own stops (a relative change of 1e-8, about 1e-4 noise variances, three iterations running; ``STALL_TOL``) spent
#: 26-30 % of a diagnosis's simulations after each fit was within 0.01 noise variances of the best it reached
#: (bench/README.md, stop 73). Not the observed change over some iterations, which a slow walk along a narrow valley
#: also shows (that rule once ended fits 11 standard errors short: ``identify._gauss_newton_solver``): the decrement
#: measures the distance left, not the pace. At a model that leaves more than the noise, both are scaled by its
#: residual variance (``ModelProblem.settled``), as its standard errors are.
SETTLED = 0.01




Sensitivity = dict[str, dict[str, float]]   # effect -> coordinate -> scale (see ``coordinates.coordinates``)


def blocks(effects: tuple[str, ...], scales: LogScales, sens: Sensitivity | None = None
           ) -> list[tuple[str, tuple[Coord, ...]]]:
    """Every effect of the model with its coordinates, in order."""
    sens = sens or {}
    return [(name, coordinates(name, scales, sens.get(name))) for name in effects]


class ModelProblem(OutputError):
    """The two-inertia FMU with ``effects`` on, fitted to the first ``stop`` samples of ``log``."""

    def __init__(self, log: DriveLog, base: DriveParams, effects: tuple[str, ...], scales: LogScales | None,
                 stop: int | None = None, sigma_load: float | None = None, fixed: dict[str, float] | None = None,
                 budget: EvaluationBudget | None = None, sens: Sensitivity | None = None, central: bool = True,
                 general: bool = False):
        super().__init__(log, base, stop, sigma_load)
        self.general = general   # through the general propagator (``same_propagator``): the screen's simulations
        self.central = central
        self.effects = effects
        self.scales = scales
        self.blocks = blocks(effects, scales, sens) if effects else []
        self.coords = [c for _, cs in self.blocks for c in cs]
        self.fixed = dict(fixed or {})
        self.budget = budget
        self.pinned: dict[int, float] = {}  # unknowns held at a value (``TwoInertiaPlugin.probe_size``)
        self.skip = 0   # the first training samples left out of the residual (simulated: they carry the state)
        self.best: tuple[float, np.ndarray] | None = None   # the lowest cost simulated and its point
        self.since_best = 0

    def residuals(self, theta: np.ndarray) -> np.ndarray:
        """``OutputError.residuals``, keeping the best point simulated and how long ago it was found."""
        before = self.evaluations
        r = super().residuals(theta)
        if self.skip:
            n = self.y_l.size
            r = r.copy()
            r[:self.skip] = 0.0
            r[n:n + self.skip] = 0.0
        if self.evaluations > before:  # a new simulation (not a cached one)
            cost = float(r @ r)
            if self.best is None or cost < self.best[0] * (1.0 - STALL_TOL):
                self.best, self.since_best = (cost, np.array(theta, dtype=float)), 0
            else:
                self.since_best += 1
        return r

    def settled(self) -> bool:
        """The last point IPOPT took a Jacobian at costs within ``SETTLED`` of the best point simulated (which may be
        one of that Jacobian's own points), and its Gauss-Newton decrement is below ``SETTLED``: no step the fit's
        linear model knows of would lower the best cost by more, or move the point by a tenth of a standard
        error. Both in the fit's own standard errors: at a model that leaves more than the noise (``misfit``: the
        residual variance s^2, in noise variances), the loop's standard errors are the sandwich's where larger
        (``TwoInertiaPlugin._cov``), s times the noise-only ones for a white misfit and more for a correlated one,
        and the tolerances here are scaled by s^2 (never below ``SETTLED``)."""
        d, best = self.newton_decrement(), self.best
        if d is None or best is None:
            return False
        tol = SETTLED * max(1.0, self.misfit(best[0]))
        return d[0] - best[0] < tol and d[1] < tol

    def misfit(self, cost: float) -> float:
        """``cost`` over what a model that reproduces the training data leaves by chance (one noise variance per
        load row, w^2 per motor row of the encoder's weights, the rows left out not counted): the residual
        variance in noise variances, ~1 at such a model. Both sensors' rows, as the cost and the Gauss-Newton
        decrement it scales (``settled``); ``sizes.residual_variance`` is a fitted model's load rows alone, the
        training cost the loop compares models by."""
        expected = (self.y_l.size - self.skip) + float(np.sum(np.square(self.w_m[self.skip:])))
        return cost / max(expected, 1.0)

    def stalled(self, after: int) -> bool:
        """No simulation has lowered the best cost (by more than ``STALL_TOL``) for ``after`` simulations."""
        return self.since_best >= after

    def spent(self, reserve: int) -> bool:
        """The budget cannot pay for ``reserve`` more simulations (an iteration's worth)."""
        b = self.budget
        return b is not None and b.limit is not None and b.used + reserve * self.stop > b.limit

    @classmethod
    def maker(cls, effects: tuple[str, ...], scales: LogScales, budget: EvaluationBudget | None = None,
              sens: Sensitivity | None = None, fixed: dict[str, float] | None = None) -> Any:
        """A factory ``make(log, base, stop, sigma_l)`` for ``identify.fit_pipeline``; ``fixed``: FMU parameters
        held."""
        return partial(_make, effects, scales, budget, sens, dict(fixed or {}))

    def values(self, theta: np.ndarray) -> dict[str, float]:
        """FMU effect parameters at ``theta``."""
        out = dict(self.fixed)
        i = BASE_UNKNOWNS
        for name, coords in self.blocks:
            out.update(fmu_values(name, coords, theta[i:i + len(coords)]))
            i += len(coords)
        return out

    def params(self, theta: np.ndarray) -> DriveParams:
        # IPOPT may probe a hair outside a bound (bound_relax_factor); the FMU would refuse e.g. b_l = -1e-12
        lo, hi = self.bounds()
        theta = np.clip(np.asarray(theta, dtype=float), lo, hi)
        p = super().params(theta).with_values(**self.values(theta))
        return same_propagator(p) if self.general else p

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = super().bounds()
        lo = np.concatenate([lo, [c.lo for c in self.coords]])
        hi = np.concatenate([hi, [c.hi for c in self.coords]])
        for i, v in self.pinned.items():
            lo[i] = hi[i] = v
        return lo, hi

    def extra_scan(self, theta: np.ndarray) -> list[np.ndarray]:
        """Steps the continuation's scan tries on the effects' coordinates: each effect's jointly, a product grid
        of x1/3 .. x3 for log coordinates and +-15 %, +-30 % of the value for the others."""
        steps = []
        i = BASE_UNKNOWNS
        for _, coords in self.blocks:
            idx = list(range(i, i + len(coords)))
            axes = [(0.0, -1.1, -0.55, 0.55, 1.1) if self.coords[j - BASE_UNKNOWNS].log
                    else tuple(theta[j] * f for f in (0.0, -0.3, -0.15, 0.15, 0.3)) for j in idx]
            for combo in _product(axes):
                if any(combo):
                    step = np.zeros(theta.size)
                    step[idx] = combo
                    steps.append(step)
            i += len(idx)
        return steps

    def jacobian(self, theta: np.ndarray) -> np.ndarray:
        """Central differences as ``OutputError`` (3e-8 in the log-parameters, 1e-6 in the initial deflection,
        ``COORD_STEP`` in an effect's coordinates); one-sided at a
        bound, where the FMU would refuse the other side (e.g. a viscous coefficient of exactly 0); a zero column for
        an unknown whose bounds hold it (IPOPT treats it as a parameter: no simulation is spent on it). ``central``
        False: forward differences (half the simulations; a candidate's refit, whose optimum only has to rank the
        candidates, uses them; the reported intervals never do)."""
        theta = np.asarray(theta, dtype=float)
        lo, hi = self.bounds()
        steps: list[tuple[np.ndarray, np.ndarray, float] | None] = []
        for i in range(theta.size):
            if lo[i] == hi[i]:
                steps.append(None)
                continue
            h = self.fd_step(i)
            up, down = theta.copy(), theta.copy()
            up[i] = min(theta[i] + h, hi[i])
            down[i] = max(theta[i] - h, lo[i]) if self.central or up[i] == theta[i] else theta[i]
            steps.append((up, down, up[i] - down[i]))
        return self.differences(theta, steps)

    def fd_step(self, i: int) -> float:
        """``OutputError.fd_step``, and at least ``COORD_STEP`` in an effect's coordinates."""
        h = super().fd_step(i)
        return max(h, COORD_STEP) if i >= BASE_UNKNOWNS else h

    def load_rows(self) -> slice:
        """The load sensor's rows of the residual vector."""
        return slice(0, self.y_l.size)


def _product(axes: list[tuple[float, ...]]) -> list[tuple[float, ...]]:
    out: list[tuple[float, ...]] = [()]
    for axis in axes:
        out = [c + (v,) for c in out for v in axis]
    return out


def _make(effects: tuple[str, ...], scales: LogScales, budget: EvaluationBudget | None, sens: Sensitivity | None,
          fixed: dict[str, float], log: DriveLog, base: DriveParams, stop: int, sigma_load: float) -> ModelProblem:
    return ModelProblem(log, base, effects, scales, stop, sigma_load, budget=budget, sens=sens, central=False,
                        fixed=fixed)


def simulate_full(log: DriveLog, problem: ModelProblem, theta: np.ndarray) -> tuple[dict[str, np.ndarray], float]:
    """The model's simulation of the WHOLE log (training + held back) with the sensor offsets of the training part,
    plus the states used to localise residuals; and what simulating the training part cost, in the FMU's model
    evaluations per training sample (the unit a budget counted from this model uses, ``EvaluationBudget``)."""
    p = problem.params(theta)
    d0 = float(theta[3]) * p.f_l / p.K_s
    q_m0 = float(problem.y_m[0])
    outputs = ("q_m", "q_l", "v_m", "v_l", "spring_torque")
    s = problem.stop
    with pooled_plant(p, q_m_start=q_m0, q_l_start=p.load_angle_at(q_m0, d0)) as plant:
        head = plant.trajectory(log.motor_torque_Nm[:s - 1], log.dt, outputs)   # the same doSteps as in one go
        work = max(plant.model_evaluations(), 1.0) / s
        tail = plant.trajectory(log.motor_torque_Nm[s - 1:-1], log.dt, outputs)
    traj = np.vstack([head, tail[1:]])
    y_m = log.motor_pos_rad + 0.5 * problem.count
    sim = {k: traj[:, i] for i, k in enumerate(outputs)}
    sim["q_l"] = sim["q_l"] + float(np.mean(log.load_pos_rad[:s] - sim["q_l"][:s]))
    sim["q_m"] = sim["q_m"] + float(np.mean(y_m[:s] - sim["q_m"][:s]))
    sim["res_l"] = log.load_pos_rad - sim["q_l"]
    sim["res_m"] = y_m - sim["q_m"]
    return sim, work


def rms(x: np.ndarray) -> float:
    return float(math.sqrt(float(np.mean(np.square(x))))) if x.size else 0.0


def one_sided_column(moved: Callable[[float], np.ndarray], r: np.ndarray, h: float, target: float) -> np.ndarray:
    """d(residual)/d(step) by a one-sided difference: ``moved(h)`` is the residual after a step ``h``, ``r`` the
    residual without it. The step is tried up to three times, rescaled after each try, until the residual moves by
    ``target`` (RMS, in noise sigmas) within a factor of 3: a linear response far above the FMU's round-off. The
    screen's candidate columns and the outside rival's (``ripple.columns``) are made so. The column is always
    divided by the step it was made with (the third step's, when none landed in range: before, that difference was
    divided by a fourth, rescaled step it was never made with)."""
    col = moved(h) - r
    for _ in range(2):
        size = rms(col)
        if size == 0.0 or 0.3 <= size / target <= 3.0:
            break
        h *= target / size
        col = moved(h) - r
    return col / h
