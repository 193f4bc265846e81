"""The paper's resolution protocols (physics.md section 3) on the plant FMU.

- ``impulse_experiment``: increments of an N-pulse experiment, fresh from rest with zero deflection.
- ``impulse_resolution``: threshold search (first amplitude of a fine ramp whose median increment exceeds eps1),
  operating amplitude A_op = A_th (1 + eps2), resolution = MAX increment of a fresh N-pulse experiment at A_op.
- ``linear_resolution``: PD set-point steps of k = 1, 2, ... encoder counts until every measured step moves the
  arm by more than eps1; resolution = max increment at that smallest consistent k.

Results are dataclasses with ``.to_frame()`` (pandas, one row per pulse / step), ``.summary()`` and ``.plot(path)``.
All lengths are metres at the arm tip; amplitudes are non-dimensional (tau* = T_m / f_m).

The inner loops (a pulse then rest, N pulses, the median test; the PD until final rest, the set-point steps) run in
compiled code over the FMU's own functions by default (``loop="compiled"``, ``ident.protocols.compiled``; 3-13x
faster, bench/protocols.py); ``loop="python"`` runs the same protocol through the Python controllers ``ImpulseController`` /
``LinearPD`` and ``Plant.step``. Both give the same increments, bit for bit.
"""
from __future__ import annotations

import math
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import pandas as pd

from ..common.checks import number, whole
from ..common.plotting import figure, save
from ..model.params import DriveParams
from ..model.plant import Plant
from ..model.pool import pooled_plant
from . import compiled
from .compiled import check_loop
from .controllers import ImpulseController, LinearPD, SettleError

_ZERO_STATE = dict(q_m_start=0.0, q_l_start=0.0, v_m_start=0.0, v_l_start=0.0)


class ThresholdNotFound(RuntimeError):
    """No pulse amplitude up to the torque limit gives a median increment above eps1."""


class NoConsistentStep(RuntimeError):
    """No set-point step up to ``max_counts`` encoder counts moves the arm consistently."""


@contextmanager
def _plant(plant_or_params: Plant | DriveParams | None, fmi_version: int) -> Iterator[Plant]:
    """A Plant: the one given, or this thread's pooled one (``ident.model.pool``) reset to the given drive
    (nominal if None); its drive checked for what the protocols need (``require_rest``)."""
    if isinstance(plant_or_params, Plant):
        require_rest(plant_or_params.params)
        yield plant_or_params
        return
    if plant_or_params is not None and not isinstance(plant_or_params, DriveParams):
        raise ValueError(f"expected a DriveParams or a Plant, got {type(plant_or_params).__name__}")
    if fmi_version not in (2, 3):
        raise ValueError(f"fmi_version = {fmi_version!r}: use 2 or 3")
    params = plant_or_params or DriveParams()
    require_rest(params)
    with pooled_plant(params, fmi_version) as plant:  # this thread's plant, reset to the drive
        yield plant


def require_rest(params: DriveParams) -> None:
    """The protocols measure increments between rests: both bodies must be able to stick, i.e. have a friction
    level > 0 (a frictionless body never stops exactly, even with viscous damping). ValueError naming the level."""
    for name, level, star in (("f_m", params.f_m, None), ("f_l", params.f_l, "f_l*")):
        if level <= 0:
            scaled = f" (f_l* = {params.f_l / params.f_m:g})" if star and params.f_m > 0 else ""
            raise ValueError(f"{name} = {level:g} N.m{scaled}: a body without friction never comes to rest, so the "
                             "resolution protocols (increments between rests) are undefined; use a friction level > 0")


def _bar(progress: bool, desc: str, unit: str) -> Any:
    """A progress bar on stderr (a disabled one when ``progress`` is False)."""
    from tqdm import tqdm

    return tqdm(desc=desc, unit=f" {unit}", disable=not progress, file=sys.stderr)


def _fresh(plant: Plant) -> None:
    """Back to time 0, at rest with zero deflection (both angles and velocities zero)."""
    plant.reset(None, **_ZERO_STATE)


class IncrementStats:
    """Statistics of ``increments_m`` (metres at the arm). The resolution is the MAX increment; the standard
    deviation uses N - 1, as in the paper's formula."""

    increments_m: np.ndarray

    @property
    def resolution_m(self) -> float:
        return float(np.max(self.increments_m))

    @property
    def median_m(self) -> float:
        return float(np.median(self.increments_m))

    @property
    def min_m(self) -> float:
        return float(np.min(self.increments_m))

    @property
    def std_m(self) -> float:
        x = self.increments_m
        return float(np.std(x, ddof=1)) if x.size > 1 else 0.0

    def stats(self) -> dict[str, float]:
        return dict(resolution_m=self.resolution_m, median_m=self.median_m, min_m=self.min_m, std_m=self.std_m,
                    mean_m=float(np.mean(self.increments_m)))


def plot_increments(increments_m: np.ndarray, path: str | Path, title: str, xlabel: str) -> Path:
    """Histogram and sequence of arm increments (µm) side by side, written to ``path`` (PNG)."""
    um = np.asarray(increments_m) * 1e6
    fig, (ax1, ax2) = figure(1, 2, size=(11, 4))
    ax1.hist(um, bins=50)
    ax1.set_xlabel("arm increment [µm]")
    ax1.set_ylabel("count")
    ax1.axvline(um.max(), color="C3", ls="--", label=f"max {um.max():.4g} µm")
    ax1.legend()
    ax2.plot(np.arange(1, um.size + 1), um, ".", ms=3)
    ax2.set_xlabel(xlabel)
    ax2.set_ylabel("arm increment [µm]")
    fig.suptitle(title)
    return save(fig, path)


# -- impulse protocol ---------------------------------------------------------------------------------------
def impulse_experiment(plant_or_params: Plant | DriveParams | None, amplitude_star: float, n_pulses: int,
                       width_s: float = 1e-3, *, fmi_version: int = 2, loop: str = "compiled") -> np.ndarray:
    """Arm increments [m] of ``n_pulses`` pulses tau* = ``amplitude_star`` for ``width_s``, each followed by rest.

    Fresh from rest with zero deflection (a given Plant is reset, keeping its parameters); the state carries over
    between pulses. ``loop``: "compiled" (C over the FMU's functions) or "python" (``ImpulseController.pulse``).
    """
    amplitude_star = number("amplitude_star", amplitude_star)
    n_pulses = whole("n_pulses", n_pulses, 1)
    width_s = number("width_s", width_s, positive=True)
    check_loop(loop)
    ctrl = ImpulseController(amplitude_star, width_s)
    with _plant(plant_or_params, fmi_version) as plant:
        _fresh(plant)
        if loop == "compiled":
            return compiled.pulses(plant, ctrl, n_pulses)[0]
        return np.array([ctrl.pulse(plant) for _ in range(n_pulses)])


def _median_exceeds(plant: Plant, amplitude_star: float, n_pulses: int, eps1_m: float,
                    width_s: float, loop: str = "compiled") -> tuple[bool, int]:
    """Is the median increment of a fresh N-pulse experiment > eps1? Stops as soon as that is decided.

    Decided early once more than N/2 increments are > eps1 (then both middle order statistics are, so the median
    is) or more than N/2 are <= eps1. Otherwise (a tie, even N) all N pulses run and np.median decides.
    Returns (passed, pulses run).
    """
    ctrl = ImpulseController(amplitude_star, width_s)
    _fresh(plant)
    if loop == "compiled":
        incs, decision = compiled.pulses(plant, ctrl, n_pulses, eps1_m)
        return (bool(np.median(incs) > eps1_m) if decision is None else decision), len(incs)
    half = n_pulses / 2
    above = below = 0
    incs = []
    for k in range(n_pulses):
        inc = ctrl.pulse(plant)
        incs.append(inc)
        if inc > eps1_m:
            above += 1
            if above > half:
                return True, k + 1
        else:
            below += 1
            if below > half:
                return False, k + 1
    return bool(np.median(incs) > eps1_m), n_pulses


@dataclass
class ImpulseResolution(IncrementStats):
    """Result of the impulse protocol. Lengths in metres at the arm tip; amplitudes in tau*."""

    params: DriveParams
    threshold_amplitude: float
    operating_amplitude: float
    increments_m: np.ndarray
    n_pulses: int
    eps1_m: float
    eps2: float
    tol_star: float
    width_s: float
    median_tests: list[tuple[float, bool, int]] = field(default_factory=list)  # (amplitude, passed, pulses run)
    elapsed_s: float = float("nan")


    def summary(self) -> dict[str, Any]:
        return dict(f_l_star=self.params.f_l_star, threshold_amplitude=self.threshold_amplitude,
                    operating_amplitude=self.operating_amplitude, n_pulses=self.n_pulses,
                    **self.stats(), n_median_tests=len(self.median_tests), elapsed_s=self.elapsed_s)

    def to_frame(self) -> pd.DataFrame:
        """One row per pulse of the operating-amplitude experiment."""
        return pd.DataFrame({"pulse": np.arange(1, len(self.increments_m) + 1),
                             "amplitude_star": self.operating_amplitude,
                             "increment_m": self.increments_m, "increment_um": self.increments_m * 1e6})

    def plot(self, path: str | Path) -> Path:
        """Histogram and increment-vs-pulse-number sequence, PNG."""
        title = (f"impulse control, f_l* = {self.params.f_l_star:.4g}: A_th = {self.threshold_amplitude:.4f}, "
                 f"A_op = {self.operating_amplitude:.4f}, resolution (max) = {self.resolution_m * 1e6:.4g} µm")
        return plot_increments(self.increments_m, path, title, "pulse number")


def find_threshold(plant: Plant, n_pulses: int = 1000, eps1_m: float = 0.1e-6, tol_star: float = 1e-4,
                   width_s: float = 1e-3, coarse_step_star: float = 0.05, max_amplitude_star: float = 20.0,
                   verify_below: int = 1, on_test: Callable[[float, bool, int], None] | None = None, *,
                   loop: str = "compiled") -> tuple[float, list[tuple[float, bool, int]]]:
    """First amplitude of the fine ramp A_i = i tol_star whose N-pulse median increment exceeds eps1.

    A coarse ramp (every ``coarse_step_star``, from 0) brackets the first pass, bisection on the fine grid narrows
    it to (fail at A - tol, pass at A). Then the ``verify_below`` fine amplitudes just below A are checked to fail
    (the one at A - tol is already known); if one passes (non-monotonic median), the search continues below it.
    Returns (A_th, list of median tests (amplitude, passed, pulses run)); ``on_test`` is called after each test
    with the same three values (progress reporting). ``loop``: as in ``impulse_experiment``.
    """
    n_pulses = whole("n_pulses", n_pulses, 1)
    eps1_m = number("eps1_m", eps1_m, positive=True)
    tol_star = number("tol_star", tol_star, positive=True)
    width_s = number("width_s", width_s, positive=True)
    coarse_step_star = number("coarse_step_star", coarse_step_star, positive=True)
    max_amplitude_star = number("max_amplitude_star", max_amplitude_star, positive=True)
    verify_below = whole("verify_below", verify_below, 1)
    check_loop(loop)
    step = max(1, round(coarse_step_star / tol_star))
    i_max = math.floor(max_amplitude_star / tol_star + 1e-9)
    cache: dict[int, bool] = {}
    tests: list[tuple[float, bool, int]] = []

    def passes(i: int) -> bool:
        if i not in cache:
            a = round(i * tol_star, 12)
            ok, used = _median_exceeds(plant, a, n_pulses, eps1_m, width_s, loop)
            cache[i] = ok
            tests.append((a, ok, used))
            if on_test is not None:
                on_test(a, ok, used)
        return cache[i]

    lo, i = -1, 0  # lo: largest index known to fail (-1: none yet)
    while not passes(i):
        lo = i
        if i >= i_max:
            raise ThresholdNotFound(f"no pulse amplitude up to tau* = {max_amplitude_star:g} gives a median "
                                    f"increment above eps1 = {eps1_m:g} m (N = {n_pulses}, width {width_s:g} s)")
        i = min(i + step, i_max)
    hi = i
    while True:
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if passes(mid):
                hi = mid
            else:
                lo = mid
        below = [j for j in range(hi - 1, hi - 1 - verify_below, -1) if j >= 0]
        lower_pass = [j for j in below if passes(j)]
        if not lower_pass:
            return round(hi * tol_star, 12), tests
        hi = min(lower_pass)
        lo = max([j for j, ok in cache.items() if not ok and j < hi], default=-1)


def impulse_resolution(plant_or_params: Plant | DriveParams | None = None, n_pulses: int = 1000,
                       eps1_m: float = 0.1e-6, eps2: float = 0.01, tol_star: float = 1e-4, width_s: float = 1e-3,
                       *, coarse_step_star: float = 0.05, max_amplitude_star: float = 20.0, verify_below: int = 1,
                       fmi_version: int = 2, progress: bool = False, loop: str = "compiled") -> ImpulseResolution:
    """The impulse protocol: threshold search, A_op = A_th (1 + eps2), a fresh N-pulse experiment at A_op.
    ``progress``: a bar on stderr counting the simulated pulses (the search's total is not known in advance).
    ``loop``: "compiled" (default, C over the FMU's functions) or "python" (``ImpulseController`` through
    ``Plant.step``); the results are the same bit for bit."""
    n_pulses = whole("n_pulses", n_pulses, 1)
    eps1_m = number("eps1_m", eps1_m, positive=True)
    eps2 = number("eps2", eps2, positive=True)
    tol_star = number("tol_star", tol_star, positive=True)
    width_s = number("width_s", width_s, positive=True)
    check_loop(loop)
    t0 = time.perf_counter()
    with _plant(plant_or_params, fmi_version) as plant, _bar(progress, "impulse protocol", "pulses") as bar:
        def on_test(a: float, ok: bool, used: int) -> None:
            bar.update(used)
            bar.set_postfix_str(f"threshold search: tau* = {a:.4f} {'passes' if ok else 'fails'}")

        a_th, tests = find_threshold(plant, n_pulses, eps1_m, tol_star, width_s, coarse_step_star,
                                     max_amplitude_star, verify_below, on_test, loop=loop)
        a_op = a_th * (1.0 + eps2)
        bar.set_postfix_str(f"experiment at A_op = {a_op:.4f}")
        incs = impulse_experiment(plant, a_op, n_pulses, width_s, loop=loop)
        bar.update(n_pulses)
        params = plant.params
    return ImpulseResolution(params, a_th, a_op, incs, n_pulses, eps1_m, eps2, tol_star, width_s, tests,
                             time.perf_counter() - t0)


# -- linear (PD) protocol -----------------------------------------------------------------------------------
@dataclass
class LinearResolution(IncrementStats):
    """Result of the linear-controller protocol. ``counts``: the smallest consistent step [encoder counts];
    ``increments_m``: its measured steps (after warm-up); ``tried``: one record per k tried."""

    params: DriveParams
    counts: int
    increments_m: np.ndarray
    n_steps: int
    warmup: int
    eps1_m: float
    gains: dict[str, float]
    tried: list[dict[str, Any]] = field(default_factory=list)
    elapsed_s: float = float("nan")


    def summary(self) -> dict[str, Any]:
        return dict(f_l_star=self.params.f_l_star, counts=self.counts, n_steps=self.n_steps,
                    **self.stats(), elapsed_s=self.elapsed_s)

    def to_frame(self) -> pd.DataFrame:
        """One row per measured step at the consistent k."""
        return pd.DataFrame({"step": np.arange(1, len(self.increments_m) + 1), "counts": self.counts,
                             "increment_m": self.increments_m, "increment_um": self.increments_m * 1e6})

    def plot(self, path: str | Path) -> Path:
        title = (f"linear PD, f_l* = {self.params.f_l_star:.4g}: consistent at {self.counts} count(s), "
                 f"resolution (max) = {self.resolution_m * 1e6:.4g} µm")
        return plot_increments(self.increments_m, path, title, "step number")


def linear_steps(plant: Plant, counts: int, n_steps: int, warmup: int = 20, *, eps1_m: float | None = None,
                 controller: LinearPD | None = None, max_settle_s: float = 60.0, loop: str = "compiled") -> np.ndarray:
    """Fresh from rest with zero deflection: ``warmup`` + ``n_steps`` PD set-point steps of ``counts``; returns
    the increments [m] of the measured steps. With ``eps1_m``, stops at the first measured step that moves the
    arm by eps1 or less (that k is then known to be inconsistent); the returned array ends with that step.

    ``loop="compiled"`` runs ``LinearPD.move`` in C over the FMU's functions (bit for bit the same); a subclass of
    ``LinearPD`` (its own ``control``) always runs in Python."""
    counts = whole("counts", counts, 1)
    check_loop(loop)
    pd_ = controller if controller is not None else LinearPD()
    _fresh(plant)
    if loop == "compiled" and type(pd_) is LinearPD:
        return compiled.pd_steps(plant, pd_, counts, n_steps, warmup, eps1_m=eps1_m, max_settle_s=max_settle_s)
    pd_.reset(plant.params, plant.sample())
    for _ in range(warmup):
        pd_.move(plant, counts, max_time_s=max_settle_s)
    out = []
    for _ in range(n_steps):
        inc = pd_.move(plant, counts, max_time_s=max_settle_s)
        out.append(inc)
        if eps1_m is not None and not inc > eps1_m:
            break
    return np.array(out)


def linear_resolution(plant_or_params: Plant | DriveParams | None = None, n_steps: int = 1000, warmup: int = 20,
                      eps1_m: float = 0.1e-6, max_counts: int = 50, *, Kp_star: float = 200.0,
                      Kd_star: float = 19.2, rate_hz: float = 1000.0, saturation_star: float = 20.0,
                      max_settle_s: float = 60.0, fmi_version: int = 2, progress: bool = False,
                      loop: str = "compiled") -> LinearResolution:
    """The linear protocol: k = 1, 2, ... counts, each a fresh run (warm-up then ``n_steps`` measured steps),
    until every measured step moves the arm by more than eps1. A k is abandoned at its first failing step.
    ``progress``: a bar on stderr counting the set-point steps run. ``loop``: "compiled" (default, C over the
    FMU's functions) or "python" (``LinearPD.move`` through ``Plant.step``); the results are the same bit for bit."""
    n_steps = whole("n_steps", n_steps, 1)
    warmup = whole("warmup", warmup, 0)
    eps1_m = number("eps1_m", eps1_m, positive=True)
    max_counts = whole("max_counts", max_counts, 1)
    check_loop(loop)
    gains = dict(Kp_star=Kp_star, Kd_star=Kd_star, rate_hz=rate_hz, saturation_star=saturation_star)
    t0 = time.perf_counter()
    tried: list[dict[str, Any]] = []
    with _plant(plant_or_params, fmi_version) as plant, _bar(progress, "linear protocol", "steps") as bar:
        for k in range(1, max_counts + 1):
            bar.set_postfix_str(f"k = {k} count(s)")
            incs = linear_steps(plant, k, n_steps, warmup, eps1_m=eps1_m, controller=LinearPD(**gains),
                                max_settle_s=max_settle_s, loop=loop)
            bar.update(warmup + len(incs))
            ok = len(incs) == n_steps and bool(np.all(incs > eps1_m))
            tried.append(dict(counts=k, steps_run=len(incs), consistent=ok,
                              failing_increment_m=None if ok else float(incs[-1])))
            if ok:
                return LinearResolution(plant.params, k, incs, n_steps, warmup, eps1_m, gains, tried,
                                        time.perf_counter() - t0)
    raise NoConsistentStep(f"no set-point step up to {max_counts} counts moved the arm by more than "
                           f"eps1 = {eps1_m:g} m in every one of {n_steps} measured steps")



__all__ = ["ImpulseResolution", "IncrementStats", "LinearResolution", "NoConsistentStep", "SettleError",
           "ThresholdNotFound", "find_threshold", "impulse_experiment", "impulse_resolution", "linear_resolution",
           "linear_steps", "plot_increments", "require_rest"]
