"""Experiment design: a torque schedule that identifies K*, J_l*, f_l* over a range of drives (issue 21, item 6).

**Family** (small on purpose: what a test bench can play and an engineer can read): a block repeated to fill the
duration, each half mirrored in sign so that the joint wanders neither way --

    +pulse(A, W), rest R, +move(L, H), rest R, -pulse(A, W), rest R, -move(L, H), rest R

a pulse of A f_m held W; a slow move: a 20 ms ramp to L f_m, held H, a 20 ms ramp down (the motor slides while the
load rings on it: this separates the scale J_l* from the ringing's K*/J_l*); a rest of zero torque (the load rings
freely and stops: frequency and Coulomb decay). L = 0 drops the moves. Levels: ``LEVELS``.

**Criterion**: robust, prior-averaged D-optimality. The unknowns are drawn over the given ranges (log-uniform, a
scrambled Sobol sample of ``PRIOR_POINTS`` drives, seeded); for each, the Fisher information of one block is
computed through the FMU (the identifier's own residuals and weights, ``identify.OutputError``, on a noise-free
simulated log) and the marginal information of (ln K*, ln J_l*, ln f_l*) (the initial deflection a nuisance:
Schur complement) enters as log det. The block maximizing the mean log det is found by coordinate exchange (each
factor over its levels in turn, two passes). Blocks that exceed ``max_torque`` or move the load by more than
``max_travel`` at any prior drive are not allowed.

**Report**: the whole schedule simulated at every prior drive and the 8 corners of the range: the relative
Cramer-Rao bound of each parameter there (noise ``noise_m`` at the arm tip), and the worst case.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Callable

import numpy as np
import pandas as pd

from ..model.params import DriveParams
from .identify import information_inverse
from .logs import LogMeta
from .result import NAMES

RAMP_S = 0.02
LEVELS = {"pulse_star": (1.5, 2.5, 4.0), "width_s": (0.5e-3, 1e-3, 2e-3), "move_star": (0.0, 1.1, 1.2, 1.5),
          "hold_s": (0.02, 0.05), "rest_s": (0.1, 0.2, 0.35)}
PRIOR_POINTS = 8
DEFAULT_RANGES = {"K_star": (1e5, 1e7), "J_l_star": (500.0, 1e4), "f_l_star": (0.01, 1.0)}


@dataclass(frozen=True)
class Block:
    """One design block (module docstring)."""

    pulse_star: float = 2.5
    width_s: float = 1e-3
    move_star: float = 1.2
    hold_s: float = 0.05
    rest_s: float = 0.2

    def seconds(self) -> float:
        move = 2 * RAMP_S + self.hold_s if self.move_star > 0 else 0.0
        return 2 * (self.width_s + move + (2 if self.move_star > 0 else 1) * self.rest_s)

    def torque_star(self, rate_hz: float) -> np.ndarray:
        """The block's torque / f_m per sample (held over each sample interval)."""
        def n(seconds: float) -> int:
            return max(1, round(seconds * rate_hz))

        half: list[np.ndarray] = [np.full(n(self.width_s), self.pulse_star), np.zeros(n(self.rest_s))]
        if self.move_star > 0:
            ramp = np.arange(n(RAMP_S)) / n(RAMP_S) * self.move_star
            half += [ramp, np.full(n(self.hold_s), self.move_star), ramp[::-1], np.zeros(n(self.rest_s))]
        one = np.concatenate(half)
        return np.concatenate([one, -one])


def schedule(block: Block, f_m: float, rate_hz: float, duration_s: float, lead_s: float = 0.05) -> np.ndarray:
    """Motor torque [N m] per sample for ``duration_s``: ``lead_s`` of rest, then ``block`` repeated."""
    n = int(round(duration_s * rate_hz))
    unit = block.torque_star(rate_hz)
    lead = np.zeros(int(round(lead_s * rate_hz)))
    reps = int(math.ceil(max(n - lead.size, 0) / unit.size)) + 1
    return np.concatenate([lead, np.tile(unit, reps)])[:n] * f_m


def prior_drives(base: DriveParams, ranges: dict[str, tuple[float, float]], points: int = PRIOR_POINTS,
                 seed: int = 0) -> list[DriveParams]:
    """``points`` drives log-uniformly spread over ``ranges`` (scrambled Sobol, seeded)."""
    from scipy.stats import qmc

    u = qmc.Sobol(3, scramble=True, seed=seed).random(points)
    lo = np.log([ranges[k][0] for k in NAMES])
    hi = np.log([ranges[k][1] for k in NAMES])
    return [base.with_values(**dict(zip(NAMES, map(float, np.exp(lo + row * (hi - lo)))))) for row in u]


def corner_drives(base: DriveParams, ranges: dict[str, tuple[float, float]]) -> list[DriveParams]:
    return [base.with_values(**dict(zip(NAMES, c))) for c in itertools.product(*(ranges[k] for k in NAMES))]


def information(drive: DriveParams, torque: np.ndarray, rate_hz: float, sigma_rad: float
                ) -> tuple[np.ndarray, float]:
    """(marginal Fisher information of ln K*, ln J_l*, ln f_l*; load travel [rad]) of ``torque`` played on
    ``drive`` from rest, through the FMU and the identifier's residuals."""
    from .identify import OutputError
    from .synthetic import synthetic_log

    log = synthetic_log(drive, torque, rate_hz=rate_hz, load_noise_m=0.0)
    theta = np.array([math.log(drive.K_star), math.log(drive.J_l_star), math.log(drive.f_l_star), 0.0])
    problem = OutputError(log, drive, sigma_load=sigma_rad)
    try:
        J = problem.jacobian(theta)
    finally:
        problem.close()
    cov = information_inverse(J.T @ J)
    return information_inverse(cov[:3, :3]), float(np.ptp(log.load_pos_rad))


def _score(block: Block, drives: list[DriveParams], f_m: float, rate_hz: float, sigma: float, max_torque: float,
           max_travel: float) -> float:
    """Mean log det of one block's marginal information over ``drives``; -inf when not allowed."""
    if block.pulse_star * f_m > max_torque or block.move_star * f_m > max_torque:
        return -math.inf
    torque = schedule(block, f_m, rate_hz, 0.05 + block.seconds())
    total = 0.0
    for d in drives:
        info, travel = information(d, torque, rate_hz, sigma)
        sign, logdet = np.linalg.slogdet(info)
        if travel > max_travel or sign <= 0:
            return -math.inf
        total += logdet
    return total / len(drives)


def optimize_block(drives: list[DriveParams], f_m: float, rate_hz: float, sigma: float, max_torque: float,
                   max_travel: float, progress: Callable[[str], None] = lambda m: None) -> tuple[Block, float]:
    """Coordinate exchange over ``LEVELS`` (two passes), from the middle levels."""
    best = Block()
    best_score = _score(best, drives, f_m, rate_hz, sigma, max_torque, max_travel)
    for _ in range(2):
        for name, levels in LEVELS.items():
            for level in levels:
                cand = replace(best, **{name: level})
                if cand == best:
                    continue
                score = _score(cand, drives, f_m, rate_hz, sigma, max_torque, max_travel)
                if score > best_score:
                    best, best_score = cand, score
            progress(f"  {name}: {getattr(best, name):g} (mean log det {best_score:.2f})")
    if not math.isfinite(best_score):
        raise ValueError("no block of the design family fits within --max-torque and --max-travel for every drive "
                         "in the range: raise them (or narrow the ranges)")
    return best, best_score


@dataclass
class Design:
    """A designed experiment: the block, the schedule and the bounds it achieves over the range."""

    block: Block
    torque_Nm: np.ndarray
    rate_hz: float
    bounds: pd.DataFrame      # one row per drive: K_star, J_l_star, f_l_star, crb_rel_<name>, travel_rad, kind
    settings: dict[str, Any]

    def to_frame(self) -> pd.DataFrame:
        """The schedule: ``time_s, motor_torque_Nm`` (the torque held from each time to the next)."""
        return pd.DataFrame({"time_s": np.arange(self.torque_Nm.size) / self.rate_hz,
                             "motor_torque_Nm": self.torque_Nm})

    def worst(self) -> dict[str, float]:
        return {k: float(self.bounds[f"crb_rel_{k}"].max()) for k in NAMES}

    def to_dict(self) -> dict[str, Any]:
        return {"block": asdict(self.block), "block_s": self.block.seconds(), "settings": self.settings,
                "worst_relative_bound": self.worst(), "bounds": self.bounds.to_dict(orient="records"),
                "family": "+pulse, rest, +move, rest, -pulse, rest, -move, rest (identify.design)"}


def design_experiment(meta: LogMeta, *, ranges: dict[str, tuple[float, float]] | None = None, max_torque: float,
                      max_travel: float, duration_s: float, noise_m: float = 5e-9, seed: int = 0,
                      progress: Callable[[str], None] = lambda m: None) -> Design:
    """The robust prior-averaged D-optimal block (module docstring) and the bounds its schedule achieves."""
    ranges = {**DEFAULT_RANGES, **(ranges or {})}
    _check_inputs(meta, ranges, max_torque, max_travel, duration_s, noise_m)
    base = DriveParams(J_m=meta.J_m_kgm2, f_m=meta.f_m_Nm, r=meta.r, arm_length=meta.arm_length_m,
                       encoder_counts_per_rev=meta.encoder_counts_per_rev)
    sigma = noise_m / meta.arm_length_m
    drives = prior_drives(base, ranges, seed=seed)
    progress(f"designing over {len(drives)} drives of the range ...")
    block, score = optimize_block(drives, base.f_m, meta.sample_rate_hz, sigma, max_torque, max_travel, progress)
    torque = schedule(block, base.f_m, meta.sample_rate_hz, duration_s)
    progress("bounds of the whole schedule over the range ...")
    rows = []
    for kind, group in (("prior", drives), ("corner", corner_drives(base, ranges))):
        for d in group:
            info, travel = information(d, torque, meta.sample_rate_hz, sigma)
            crb = np.sqrt(np.diag(information_inverse(info)))
            rows.append({"kind": kind, **{k: getattr(d, k) for k in NAMES},
                         **{f"crb_rel_{k}": float(c) for k, c in zip(NAMES, crb)}, "travel_rad": travel})
    settings = {"ranges": ranges, "max_torque_Nm": max_torque, "max_travel_rad": max_travel,
                "duration_s": duration_s, "noise_m": noise_m, "sample_rate_hz": meta.sample_rate_hz,
                "mean_log_det_per_block": score, "seed": seed}
    return Design(block, torque, meta.sample_rate_hz, pd.DataFrame(rows), settings)


def _check_inputs(meta: LogMeta, ranges: dict[str, tuple[float, float]], max_torque: float, max_travel: float,
                  duration_s: float, noise_m: float) -> None:
    """Named errors before any simulation."""
    if meta.J_m_kgm2 is None or meta.f_m_Nm is None or meta.encoder_counts_per_rev is None:
        raise ValueError("the sidecar needs J_m_kgm2, f_m_Nm and encoder_counts_per_rev to design an experiment")
    for name, (lo, hi) in ranges.items():
        if name not in NAMES:
            raise ValueError(f"unknown range {name!r}; use {', '.join(NAMES)}")
        if not (0 < lo <= hi and math.isfinite(hi)):
            raise ValueError(f"range of {name}: [{lo!r}, {hi!r}] must satisfy 0 < low <= high")
    for flag, value in (("--max-torque", max_torque), ("--max-travel", max_travel), ("--duration", duration_s),
                        ("--noise-m", noise_m)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{flag} = {value!r}: must be > 0")
    smallest = min(LEVELS["pulse_star"]) * meta.f_m_Nm
    if max_torque < smallest:
        raise ValueError(f"--max-torque = {max_torque:g} N m: the smallest pulse of the family is "
                         f"{min(LEVELS['pulse_star'])} f_m = {smallest:g} N m (pulses below ~1.5 f_m hardly move "
                         "the motor)")
