"""The closed-form engine: exact propagation of modes whose equations are linear with constant forcing.

Per mode, the affine right-hand side of ``HybridPlant`` is read off at the unit vectors (exact for affine
functions): z' = M z with z = [x, T_cmd, 1], and the guards are linear forms E z. Over a sub-step h (chosen so that
the spectral radius of M times h is at most ``RHO_H``), z(s h) = sum_k s^k S_k z0 with S_k = (M h)^k / k!, so guard
i is the polynomial p_i(s) = sum_k (E S_k z0)_i s^k on s in [0, 1]. Its first zero is found rigorously:

* on a grid of G cells, p >= min(end values) - max|p''| cell^2 / 8 inside a cell (Taylor), with
  max|p''| <= sum_k k (k-1) |c_k|; a cell whose bound is positive holds no zero;
* a cell that fails is halved until the bound clears or a negative value is found, then brentq on p;
* a guard that starts at zero (just switched on) is divided by s^m, m its number of vanishing coefficients, and the
  quotient (positive at 0+ by the Karnopp decision) is checked instead.

A stuck body's angle is copied, not propagated, so that it is exactly constant.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm
from scipy.optimize import brentq

from .engines import FRESH_TOL
from .plant import LOAD, MOTOR, STUCK, Guard, HybridPlant, Mode, Vector

RHO_H = 1.0            # spectral radius of M times the sub-step
GRID = 16              # cells per sub-step for the zero search
SERIES_TOL = 1e-20     # last power-series term, relative (scaled coordinates)
MAX_HALVINGS = 40


@dataclass
class _ModeData:
    h: float
    m: int                     # sub-steps per sample
    labels: list[Guard]
    scales: np.ndarray         # per-guard scale
    phi: np.ndarray            # expm(M h)
    S: np.ndarray              # (K+1, n+2, n+2): (M h)^k / k!
    Q: np.ndarray              # ((K+1) n_g, n+2): E S_k, stacked
    k2: np.ndarray             # k (k-1) for the p'' bound
    grid_T: np.ndarray         # (GRID+1, K+1): s_j^k on the unit grid


@dataclass
class LinearEngine:
    """Exact piecewise-linear propagation (see the module docstring); ``dt`` is learnt from the first call."""

    plant: HybridPlant
    dt: float = 1e-3
    cache: dict = field(default_factory=dict)
    steps: int = 0

    def __post_init__(self) -> None:
        if not self.plant.effects.piecewise_linear() or self.plant.track_energy:
            raise ValueError("LinearEngine needs piecewise-linear effects and no energy tracking (use RKEngine)")
        p, d = self.plant, self.plant.drive
        w, ds = d.omega_max, p.d_scale
        scales = [ds / d.r, ds, ds * w / d.r, ds * w]
        if p.i_lag >= 0:
            scales.append(d.f_m)
        scales += list(p.effects.hysteresis.break_torques) if p.n_elements else []
        self.zscale = np.array(scales + [d.f_m, 1.0])

    # ---- per mode ----
    def _affine(self, mode: Mode) -> tuple[np.ndarray, np.ndarray, list[Guard]]:
        """(M, E, guard labels) of ``mode`` from the plant's own functions at the unit vectors."""
        p = self.plant
        n = p.n_states
        rhs = p.rhs_for(mode)
        labels, gfun = p.guards_for(mode)
        zero = [0.0] * n
        f0, g0 = np.array(rhs(zero, 0.0)), np.array(gfun(zero, 0.0))
        M = np.zeros((n + 2, n + 2))
        E = np.zeros((len(labels), n + 2))
        for j in range(n + 1):
            x = list(zero)
            u = 1.0 if j == n else 0.0
            if j < n:
                x[j] = 1.0
            M[:n, j] = np.array(rhs(x, u)) - f0
            E[:, j] = np.array(gfun(x, u)) - g0
        M[:n, n + 1], E[:, n + 1] = f0, g0
        return M, E, labels

    def _mode(self, mode: Mode, dt: float) -> _ModeData:
        key = (mode, dt)
        data = self.cache.get(key)
        if data is None:
            data = self.cache[key] = self._build(mode, dt)
        return data

    def _build(self, mode: Mode, dt: float) -> _ModeData:
        M, E, labels = self._affine(mode)
        rho = float(np.max(np.abs(np.linalg.eigvals(M)))) if M.any() else 0.0
        m = max(1, math.ceil(rho * dt / RHO_H))
        h = dt / m
        D = self.zscale
        terms = [np.eye(M.shape[0])]
        Mh = M * h
        for k in range(1, 200):
            nxt = terms[-1] @ Mh / k
            terms.append(nxt)
            if k >= 6 and np.max(np.abs(nxt * D[None, :] / D[:, None])) < SERIES_TOL:
                break
        S = np.array(terms)
        K = len(terms) - 1
        ks = np.arange(K + 1)
        grid = np.linspace(0.0, 1.0, GRID + 1)
        Q = np.einsum("ij,kjl->kil", E, S).reshape(-1, M.shape[0])
        return _ModeData(h, m, labels, np.array([g.scale for g in labels]), expm(Mh), S, Q,
                         (ks * (ks - 1)).astype(float), grid[:, None] ** ks[None, :])

    # ---- one call ----
    def prepare(self, dt: float) -> None:
        """The sample interval of the coming run (sub-steps divide it evenly)."""
        self.dt = dt

    def propagate(self, x: Vector, u: float, mode: Mode, span: float) -> tuple[Vector, float, Guard | None]:
        data = self._mode(mode, self.dt)
        z = np.array(list(x) + [u, 1.0])
        t = 0.0
        while span - t > 1e-15 * self.dt:
            s_max = min(1.0, (span - t) / data.h)
            hit = self._first_zero(data, z, s_max)
            self.steps += 1
            if hit is not None:
                s, guard = hit
                z = self._at(data, z, s)
                return self._exact(x, z, mode), t + s * data.h, guard
            z = data.phi @ z if s_max == 1.0 else self._at(data, z, s_max)
            t += s_max * data.h
        return self._exact(x, z, mode), span, None

    @staticmethod
    def _at(data: _ModeData, z: np.ndarray, s: float) -> np.ndarray:
        """z(s h) by the power series (Horner)."""
        out = data.S[-1] @ z
        for k in range(len(data.S) - 2, -1, -1):
            out = out * s + data.S[k] @ z
        return out

    def _exact(self, x0: Vector, z: np.ndarray, mode: Mode) -> Vector:
        x = z[:self.plant.n_states].tolist()
        for body in (MOTOR, LOAD):
            if mode[body] == STUCK:
                x[body], x[2 + body] = x0[body], 0.0
        return x

    # ---- zeros of the guard polynomials ----
    def _first_zero(self, data: _ModeData, z: np.ndarray, s_max: float) -> tuple[float, Guard] | None:
        """Earliest zero in (0, s_max] of any guard polynomial, with the guard (None if there is none)."""
        C = (data.Q @ z).reshape(-1, len(data.labels))          # (K+1, n_g): guard i = sum_k C[k, i] s^k
        fresh = np.abs(C[0]) <= FRESH_TOL * data.scales
        if s_max == 1.0 and not fresh.any():                     # the common case: one matrix product decides
            V = data.grid_T @ C
            lower = np.minimum(V[:-1], V[1:]) - (data.k2 @ np.abs(C)) * (0.125 / GRID**2)
            if lower.min() > 0.0:
                return None
        live = np.ones(C.shape[1], dtype=bool)
        for i in np.flatnonzero(fresh):
            q = _strip(C[:, i], data.scales[i])
            if q is None:
                live[i] = False                                  # identically ~0: never crosses
            elif q[0] < 0.0:
                return 0.0, data.labels[i]                       # wrong assumed direction: switch at once
            else:
                C[:, i] = np.concatenate([q, np.zeros(C.shape[0] - q.size)])
        T = data.grid_T if s_max == 1.0 else (np.linspace(0.0, s_max, GRID + 1)[:, None]
                                              ** np.arange(C.shape[0])[None, :])
        V = T @ C
        k2 = data.k2 @ np.abs(C)
        lower = np.minimum(V[:-1], V[1:]) - k2[None, :] * (s_max / GRID) ** 2 / 8.0
        best: tuple[float, Guard] | None = None
        for i in np.flatnonzero(live & np.any(lower <= 0.0, axis=0)):
            for j in np.flatnonzero(lower[:, i] <= 0.0):
                if best is not None and j * s_max / GRID >= best[0]:
                    break
                root = _cell_zero(C[:, i], j * s_max / GRID, (j + 1) * s_max / GRID, float(k2[i]))
                if root is not None:
                    if best is None or root < best[0]:
                        best = (root, data.labels[i])
                    break
        return best


def _strip(c: np.ndarray, scale: float) -> np.ndarray | None:
    """p(s) / s^m for a guard that starts at zero (m leading coefficients negligible); None if all are."""
    big = np.flatnonzero(np.abs(c) > FRESH_TOL * 1e-3 * scale)
    big = big[big > 0]
    return None if big.size == 0 else c[big[0]:].copy()


def _poly(q: np.ndarray, s: float) -> float:
    out = 0.0
    for c in q[::-1]:
        out = out * s + c
    return float(out)


def _cell_zero(q: np.ndarray, a: float, b: float, k2: float, depth: int = 0) -> float | None:
    """First zero of q in [a, b] (q(a) >= 0 assumed; s <= 1 so |q''| <= k2), by halving, then brentq."""
    va, vb = _poly(q, a), _poly(q, b)
    if vb < 0.0:
        if va <= 0.0:
            return a
        return brentq(lambda s: _poly(q, s), a, b, xtol=1e-15, rtol=4 * np.finfo(float).eps)
    if min(va, vb) - k2 * (b - a) ** 2 / 8.0 > 0.0 or depth >= MAX_HALVINGS:
        return None
    mid = 0.5 * (a + b)
    left = _cell_zero(q, a, mid, k2, depth + 1)
    return left if left is not None else _cell_zero(q, mid, b, k2, depth + 1)
