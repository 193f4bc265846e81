"""Randomized, realistic "measured" drive logs with known truth, for testing the product against data it did not
make (issues 16 and 21). Imports nothing from ``ident`` or ``fmu_build``.

Every case is a pure function of its seed (numpy ``default_rng([seed, stream, ...])``, one stream per concern so
that e.g. the same seed gives the same drive whatever the excitation or effect):

* drive: K* log-uniform 1e5-1e7, J_l* 500-1e4, f_l* 0.01-1; J_m = 2e-5 and f_m = 0.01 times log-uniform 0.5-2;
  r one of the catalog ratios 1/50 .. 1/160; arm 0.15-0.5 m; encoder 4096 .. 65536 counts/rev;
* sample rate one of 1, 2, 2.5, 4, 5, 8, 10 kHz;
* sensors: the encoder floor-quantized (motor angle drawn inside the first count, so the quantization phase is
  random); the load sensor = load angle + offset (uniform +-5 mrad) + white noise of 1-20 nm at the arm
  (log-uniform), in rad;
* start: at rest, the spring wound to a deflection drawn uniformly inside 90 % of the static band (the deflection
  both bodies hold at zero torque, for every plant of the case: with and without its effects);
* excitation: ``excitations.KINDS``.

The log follows the product's format (physics.md section 4): n + 1 samples t_k = k / rate; ``motor_torque_Nm[k]``
is the command held over [t_k, t_k+1) (the last one, after the log, is what the excitation would send next).
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from . import excitations as exc
from .effects import (
    CLASSES,
    LIBRARY_EFFECTS,
    OUTSIDE_LIBRARY_EFFECTS,
    VARIANTS,
    WEAK_SNR,
    EffectFamily,
    RunStats,
    draw_family,
    merge,
    weak_magnitude,
)
from ..stored import atomic_write, stored
from .engines import RKEngine, simulate
from .linear import LinearEngine
from .plant import Drive, Effects, HybridPlant

RATES_HZ = (1000.0, 2000.0, 2500.0, 4000.0, 5000.0, 8000.0, 10000.0)
RATIOS = (1 / 50, 1 / 80, 1 / 100, 1 / 120, 1 / 160)
ENCODERS = (4096, 8192, 10000, 12566, 16384, 20000, 65536)
IDENTIFICATION_KINDS = ("default", "steps", "pulse_train", "bidirectional", "pd_steps", "chirp")
DEFAULT_DURATION_S = 4.0
RTOL = 1e-10
SIDECAR_KEYS = ("r", "J_m_kgm2", "f_m_Nm", "arm_length_m", "encoder_counts_per_rev", "sample_rate_hz")
_STREAMS = {"drive": 0, "sensors": 1, "excitation": 2, "start": 3, "effect": 4, "noise": 5, "choice": 6}


@dataclass(frozen=True)
class Sensors:
    """The measurement chain: load sensor noise at the arm tip [m] and zero offset [rad]."""

    noise_m: float
    offset_rad: float


@dataclass
class Truth:
    """Everything the log was made from. Angles in rad, SI units; ``snr`` = each effect's own signal (RMS of the
    load angle with minus without it) over the load noise sigma."""

    seed: int
    scenario: str
    K_star: float
    J_l_star: float
    f_l_star: float
    si: dict
    excitation: dict
    sample_rate_hz: float
    duration_s: float
    noise_sigma_rad: float
    noise_m: float
    offset_rad: float
    initial_deflection_rad: float
    initial_motor_angle_rad: float
    effects: dict = field(default_factory=dict)          # Effects.to_dict(): parameters and shapes
    effect_names: list = field(default_factory=list)
    variants: dict = field(default_factory=dict)         # effect -> shape variant and its drawn details
    magnitudes: dict = field(default_factory=dict)       # effect -> [magnitude, unit]
    magnitude_classes: dict = field(default_factory=dict)
    snr: dict = field(default_factory=dict)
    engine: str = ""

    def to_dict(self) -> dict:
        return _plain(asdict(self))


@dataclass
class GeneratedLog:
    """A generated log: the four measured columns, the sidecar (exactly the product's keys), the truth, and the
    true angles (for tests)."""

    time_s: np.ndarray
    motor_torque_Nm: np.ndarray
    motor_pos_rad: np.ndarray
    load_pos_rad: np.ndarray
    sidecar: dict
    truth: Truth
    true_motor_pos_rad: np.ndarray
    true_load_pos_rad: np.ndarray

    def columns(self) -> dict[str, np.ndarray]:
        return {"time_s": self.time_s, "motor_torque_Nm": self.motor_torque_Nm, "motor_pos_rad": self.motor_pos_rad,
                "load_pos_rad": self.load_pos_rad}

    def to_frame(self) -> pd.DataFrame:
        """The measured columns and the true angles (``true_motor_pos_rad``, ``true_load_pos_rad``)."""
        return pd.DataFrame({**self.columns(), "true_motor_pos_rad": self.true_motor_pos_rad,
                             "true_load_pos_rad": self.true_load_pos_rad})

    def plot(self, path: str | Path) -> Path:
        """Torque, encoder and load sensor against time, with the true angles; saved to ``path``."""
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, axes = plt.subplots(3, 1, sharex=True, figsize=(9, 7))
        axes[0].plot(self.time_s, self.motor_torque_Nm, drawstyle="steps-post")
        axes[0].set_ylabel("motor torque [N m]")
        axes[1].plot(self.time_s, self.motor_pos_rad, label="encoder")
        axes[1].plot(self.time_s, self.true_motor_pos_rad, label="true", lw=0.8)
        axes[1].set_ylabel("motor angle [rad]")
        axes[2].plot(self.time_s, self.load_pos_rad - self.truth.offset_rad, label="sensor - offset")
        axes[2].plot(self.time_s, self.true_load_pos_rad, label="true", lw=0.8)
        axes[2].set_ylabel("load angle [rad]")
        axes[2].set_xlabel("time [s]")
        for ax in axes[1:]:
            ax.legend(loc="best")
        t = self.truth
        fig.suptitle(f"seed {t.seed} {t.scenario}: {t.excitation['kind']}, K* {t.K_star:.3g}, J_l* {t.J_l_star:.3g}, "
                     f"f_l* {t.f_l_star:.3g}; effects: {', '.join(t.effect_names) or 'none'}")
        fig.tight_layout()
        fig.savefig(path)
        plt.close(fig)
        return Path(path)

    def write(self, directory: str | Path, stem: str = "log", truth: bool = True) -> tuple[Path, Path]:
        """Write ``<stem>.csv`` and its sidecar ``<stem>.json`` (the product's format; numbers with 17 significant
        digits, so they read back exactly), and ``<stem>.truth.json`` when ``truth``. Returns (csv, sidecar)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        csv_path, json_path = directory / f"{stem}.csv", directory / f"{stem}.json"
        table = np.column_stack(list(self.columns().values()))
        atomic_write(csv_path, lambda f: np.savetxt(f, table, delimiter=",", fmt="%.17g",
                                                    header=",".join(self.columns()), comments=""))
        atomic_write(json_path, lambda f: f.write(json.dumps(self.sidecar, indent=2).encode() + b"\n"))
        if truth:
            atomic_write(directory / f"{stem}.truth.json",
                         lambda f: f.write(json.dumps(self.truth.to_dict(), indent=2).encode() + b"\n"))
        return csv_path, json_path


def _plain(value):
    """JSON-ready copy (numpy scalars and arrays to Python numbers and lists)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


# ------------------------------------------------------------------------------------------------ draws -------

def _rng(seed: int, stream: str, *extra: int) -> np.random.Generator:
    return np.random.default_rng([seed, _STREAMS[stream], *extra])


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def draw_drive(seed: int) -> Drive:
    """The drive of case ``seed`` (see the module docstring for the ranges)."""
    rng = _rng(seed, "drive")
    K_star, J_l_star, f_l_star = (_log_uniform(rng, 1e5, 1e7), _log_uniform(rng, 500, 1e4),
                                  _log_uniform(rng, 0.01, 1.0))
    J_m, f_m = 2e-5 * _log_uniform(rng, 0.5, 2.0), 0.01 * _log_uniform(rng, 0.5, 2.0)
    return Drive.from_nondim(K_star, J_l_star, f_l_star, J_m=J_m, f_m=f_m, r=float(rng.choice(RATIOS)),
                             arm_length=float(rng.uniform(0.15, 0.5)),
                             encoder_counts_per_rev=int(rng.choice(ENCODERS)))


def draw_rate_and_sensors(seed: int) -> tuple[float, Sensors]:
    rng = _rng(seed, "sensors")
    rate = float(rng.choice(RATES_HZ))
    return rate, Sensors(noise_m=_log_uniform(rng, 1e-9, 20e-9), offset_rad=float(rng.uniform(-5e-3, 5e-3)))


def draw_start(seed: int, drive: Drive, plants: list[HybridPlant]) -> tuple[float, float]:
    """(q_m0, d0): the motor angle inside the first count, and a deflection inside every plant's static band."""
    rng = _rng(seed, "start")
    q_m0 = float(rng.uniform(0.0, 1.0)) * drive.count_rad
    fraction = float(rng.uniform(-0.9, 0.9))
    return q_m0, min((_deflection_in_band(p, q_m0, fraction) for p in plants), key=abs)


def _deflection_in_band(plant: HybridPlant, q_m0: float, fraction: float) -> float:
    """The deflection whose spring torque is ``fraction`` of the way to the edge of the band both bodies hold."""
    lo_l, hi_l = plant.frictions[1].band(q_m0)
    lo_m, hi_m = plant.frictions[0].band(q_m0)
    g = plant.gear(q_m0)
    hi, lo = min(hi_l, -lo_m / g), max(lo_l, -hi_m / g)    # motor net torque at zero command: -g tau
    torque = fraction * (hi if fraction > 0 else -lo)
    a, b = -1.0, 1.0
    for _ in range(200):     # bisection: springs are monotone (three-slope: region chosen below)
        mid = 0.5 * (a + b)
        if plant.spring_fn(plant.region_of(mid))(mid) < torque:
            a = mid
        else:
            b = mid
    return 0.5 * (a + b)


# ------------------------------------------------------------------------------------------------ runs --------

@dataclass(frozen=True)
class Case:
    """A case without its effects: drive, rate, sensors, excitation, duration."""

    seed: int
    drive: Drive
    rate_hz: float
    sensors: Sensors
    excitation: exc.Excitation
    duration_s: float

    @property
    def n(self) -> int:
        return round(self.duration_s * self.rate_hz)

    @property
    def sigma(self) -> float:
        """Load sensor noise [rad]."""
        return self.sensors.noise_m / self.drive.arm_length


@dataclass
class Run:
    """A simulated run: true angles at the n + 1 samples, the n + 1 logged commands, optional full states."""

    q_m: np.ndarray
    q_l: np.ndarray
    torque: np.ndarray
    states: np.ndarray | None
    plant: HybridPlant
    engine: str


def make_case(seed: int, kind: str, duration_s: float = DEFAULT_DURATION_S, rate_hz: float | None = None) -> Case:
    """Drive, rate, sensors and a ``kind`` excitation of case ``seed``."""
    if kind not in exc.KINDS:
        raise ValueError(f"unknown excitation {kind!r}; known: {', '.join(exc.KINDS)}")
    if not duration_s > 0.0:
        raise ValueError(f"duration_s = {duration_s!r}: must be > 0")
    drive = draw_drive(seed)
    rate, sensors = draw_rate_and_sensors(seed)
    rate = float(rate_hz) if rate_hz is not None else rate
    excitation = exc.draw(kind, _rng(seed, "excitation", exc.KINDS.index(kind)), drive.f_m, rate, duration_s,
                          T_c=drive.T_c, count_rad=drive.count_rad)
    return Case(seed, drive, rate, sensors, excitation, duration_s)


def engine_for(plant: HybridPlant, rtol: float = RTOL):
    """The closed-form engine where every mode is linear, else adaptive DOP853."""
    if plant.effects.piecewise_linear() and not plant.track_energy:
        return LinearEngine(plant)
    return RKEngine(plant, rtol=rtol)


def run(case: Case, effects: Effects, start: tuple[float, float], keep_states: bool = False,
        engine=None) -> Run:
    """Simulate ``case`` with ``effects`` from ``start`` = (q_m0, d0)."""
    plant = HybridPlant(case.drive, effects)
    engine = engine or engine_for(plant)
    x, mode = plant.initial_state(*start)
    command = case.excitation.command()
    record, commands = simulate(plant, engine, x, mode, 1.0 / case.rate_hz, command, case.n, keep_states)
    last = command(case.n, float(record.q_m[-1])) if case.excitation.pd is not None else 0.0
    return Run(record.q_m, record.q_l, np.append(commands, last), record.states, plant, type(engine).__name__)


def stats_of(clean: Run, sigma: float) -> RunStats:
    """Deflection scale and slip speeds of a clean run (with states)."""
    s, plant = clean.states, clean.plant
    d = plant.drive.r * s[:, 0] - s[:, 1]
    v_m, v_l = np.abs(s[:, 2]), np.abs(s[:, 3])
    d95 = float(np.percentile(np.abs(d), 95)) or plant.d_scale
    return RunStats(d95=d95, v_m=float(np.median(v_m[v_m > 0])) if np.any(v_m > 0) else plant.v_scale,
                    v_l=float(np.median(v_l[v_l > 0])) if np.any(v_l > 0) else plant.v_scale * plant.drive.r,
                    sigma=sigma)


def measure(case: Case, r: Run) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time, encoder, load sensor) of a run: floor-quantized encoder, noisy offset load sensor."""
    c = case.drive.count_rad
    noise = _rng(case.seed, "noise").normal(0.0, case.sigma, r.q_l.size)
    return (np.arange(r.q_m.size) / case.rate_hz, np.floor(r.q_m / c) * c,
            r.q_l + case.sensors.offset_rad + noise)


def rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(a))))


# ------------------------------------------------------------------------------------------------ scenarios ---

@dataclass
class _Context:
    """A case and its clean run from the base start (cached: every magnitude class of a case shares it)."""

    case: Case
    start: tuple[float, float]
    clean: Run
    stats: RunStats


@lru_cache(maxsize=32)
def _context(seed: int, kind: str, duration_s: float, rate_hz: float | None) -> _Context:
    case = make_case(seed, kind, duration_s, rate_hz)
    start = draw_start(seed, case.drive, [HybridPlant(case.drive)])
    clean = run(case, Effects(), start, keep_states=True)
    return _Context(case, start, clean, stats_of(clean, case.sigma))


def _family(ctx: _Context, name: str, variant: str | None) -> EffectFamily:
    known = LIBRARY_EFFECTS + OUTSIDE_LIBRARY_EFFECTS
    if name not in known:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(known)}")
    d = ctx.case.drive
    rng = _rng(ctx.case.seed, "effect", known.index(name))
    return draw_family(name, rng, ctx.stats, d.r, d.f_m, d.f_l, d.K_s, variant)


@lru_cache(maxsize=256)
def _weak(seed: int, kind: str, duration_s: float, rate_hz: float | None, name: str,
          variant: str | None) -> tuple[float, float, int]:
    """(weak magnitude, its signal [rad], simulations used) of effect ``name`` in case ``seed``."""
    ctx = _context(seed, kind, duration_s, rate_hz)
    family = _family(ctx, name, variant)

    def signal(effects: Effects) -> float:
        return rms(run(ctx.case, effects, ctx.start).q_l - ctx.clean.q_l)
    return weak_magnitude(family, signal, WEAK_SNR * ctx.case.sigma)


def _generate(seed: int, scenario: str, kind: str, duration_s: float, rate_hz: float | None,
              specs: list[tuple[str, str | None, str | float]]) -> GeneratedLog:
    """The log of case ``seed`` with effects ``specs`` = [(name, variant or None, magnitude class or the
    magnitude itself)]."""
    ctx = _context(seed, kind, duration_s, rate_hz)
    parts, truth_bits = [], {"variants": {}, "magnitudes": {}, "magnitude_classes": {}}
    for name, variant, cls in specs:
        if not isinstance(cls, float) and cls not in CLASSES:
            raise ValueError(f"magnitude class {cls!r}: use one of {', '.join(CLASSES)}")
        family = _family(ctx, name, variant)
        if isinstance(cls, float):
            m, cls = min(cls, family.cap), "given"
        else:
            m = min(_weak(seed, kind, duration_s, rate_hz, name, variant)[0] * CLASSES[cls], family.cap)
        parts.append(family.build(m))
        truth_bits["variants"][name] = {"variant": family.variant, **family.shape}
        truth_bits["magnitudes"][name] = [m, family.unit]
        truth_bits["magnitude_classes"][name] = cls if m < family.cap else f"{cls} (capped at {family.cap:g})"
    effects = merge(*parts) if parts else Effects()
    plants = [HybridPlant(ctx.case.drive), HybridPlant(ctx.case.drive, effects)]
    start = draw_start(seed, ctx.case.drive, plants)
    full = ctx.clean if not parts and start == ctx.start else run(ctx.case, effects, start)
    snr = _snr(ctx, start, parts, specs, full)
    return _assemble(ctx.case, scenario, full, start, effects, [s[0] for s in specs], snr, truth_bits)


def _snr(ctx: _Context, start: tuple[float, float], parts: list[Effects], specs: list, full: Run) -> dict:
    """Each effect's own signal over the noise: RMS(q_l with all effects - q_l with all but this one) / sigma."""
    out = {}
    for i, (name, _, _) in enumerate(specs):
        others = [p for j, p in enumerate(parts) if j != i]
        if not others and start == ctx.start:
            without = ctx.clean.q_l
        else:
            without = run(ctx.case, merge(*others) if others else Effects(), start).q_l
        out[name] = rms(full.q_l - without) / ctx.case.sigma
    return out


def _assemble(case: Case, scenario: str, r: Run, start: tuple[float, float], effects: Effects, names: list[str],
              snr: dict, bits: dict) -> GeneratedLog:
    d = case.drive
    time_s, encoder, load = measure(case, r)
    sidecar = {"r": d.r, "J_m_kgm2": d.J_m, "f_m_Nm": d.f_m, "arm_length_m": d.arm_length,
               "encoder_counts_per_rev": d.encoder_counts_per_rev, "sample_rate_hz": case.rate_hz}
    truth = Truth(seed=case.seed, scenario=scenario, K_star=d.K_star, J_l_star=d.J_l_star, f_l_star=d.f_l_star,
                  si=asdict(d), excitation={"kind": case.excitation.kind, **case.excitation.params},
                  sample_rate_hz=case.rate_hz, duration_s=case.duration_s, noise_sigma_rad=case.sigma,
                  noise_m=case.sensors.noise_m, offset_rad=case.sensors.offset_rad,
                  initial_deflection_rad=start[1], initial_motor_angle_rad=start[0], effects=effects.to_dict(),
                  effect_names=names, snr=snr, engine=r.engine, **bits)
    return GeneratedLog(time_s, r.torque, encoder, load, sidecar, truth, r.q_m, r.q_l)


@stored
def identification_case(seed: int, excitation: str | None = None, duration_s: float = DEFAULT_DURATION_S,
                        rate_hz: float | None = None) -> GeneratedLog:
    """A clean log for identification; ``excitation`` None draws one of ``IDENTIFICATION_KINDS``."""
    if excitation is None:
        excitation = IDENTIFICATION_KINDS[int(_rng(seed, "choice").integers(len(IDENTIFICATION_KINDS)))]
    return _generate(seed, "identification", excitation, duration_s, rate_hz, [])


@stored
def clean_case(seed: int, excitation: str = "default", duration_s: float = DEFAULT_DURATION_S,
               rate_hz: float | None = None) -> GeneratedLog:
    """A log with no hidden effect (diagnosis must name nothing)."""
    return _generate(seed, "clean", excitation, duration_s, rate_hz, [])


def _library_effect(effect: str) -> None:
    if effect not in LIBRARY_EFFECTS:
        raise ValueError(f"effect {effect!r} is not a library effect; use one of {', '.join(LIBRARY_EFFECTS)}")


@stored
def diagnosis_case(seed: int, effect: str, magnitude_class: str, excitation: str = "default",
                   duration_s: float = DEFAULT_DURATION_S, variant: str | None = None,
                   rate_hz: float | None = None) -> GeneratedLog:
    """A log with one library effect hidden at ``magnitude_class`` (weak / medium / strong)."""
    _library_effect(effect)
    return _generate(seed, "diagnosis", excitation, duration_s, rate_hz, [(effect, variant, magnitude_class)])


@stored
def sized_case(seed: int, effect: str, magnitude: float, excitation: str = "default", variant: str | None = None,
               duration_s: float = DEFAULT_DURATION_S, rate_hz: float | None = None) -> GeneratedLog:
    """A log with one library effect hidden at ``magnitude`` (the effect's own unit, ``effects.py``; capped as
    the classes are), in the same case (drive, excitation, noise) as ``diagnosis_case(seed, ...)``: to ask how small
    an effect a tool can find."""
    _library_effect(effect)
    if not magnitude > 0:
        raise ValueError(f"magnitude = {magnitude}: must be > 0")
    return _generate(seed, "diagnosis", excitation, duration_s, rate_hz, [(effect, variant, float(magnitude))])


@stored
def two_effect_case(seed: int, effects: tuple[str, str] | None = None,
                    magnitude_classes: tuple[str, str] | None = None, excitation: str = "default",
                    duration_s: float = DEFAULT_DURATION_S, rate_hz: float | None = None) -> GeneratedLog:
    """Two different library effects; drawn (with classes medium / strong) when not given."""
    rng = _rng(seed, "choice", 2)
    if effects is None:
        i, j = rng.choice(len(LIBRARY_EFFECTS), size=2, replace=False)
        effects = (LIBRARY_EFFECTS[int(i)], LIBRARY_EFFECTS[int(j)])
    if magnitude_classes is None:
        magnitude_classes = tuple(str(c) for c in rng.choice(("medium", "strong"), size=2))
    if effects[0] == effects[1]:
        raise ValueError(f"two_effect_case needs two different effects, got {effects}")
    specs = [(e, None, c) for e, c in zip(effects, magnitude_classes)]
    return _generate(seed, "two_effect", excitation, duration_s, rate_hz, specs)


@stored
def outside_library_case(seed: int, effect: str | None = None, magnitude_class: str | None = None,
                         excitation: str = "default", duration_s: float = DEFAULT_DURATION_S,
                         rate_hz: float | None = None) -> GeneratedLog:
    """An effect outside the product's library (actuator lag or friction ripple)."""
    rng = _rng(seed, "choice", 3)
    effect = effect or OUTSIDE_LIBRARY_EFFECTS[int(rng.integers(len(OUTSIDE_LIBRARY_EFFECTS)))]
    magnitude_class = magnitude_class or str(rng.choice(("medium", "strong")))
    if effect not in OUTSIDE_LIBRARY_EFFECTS:
        raise ValueError(f"effect {effect!r} is not outside the library; use one of "
                         f"{', '.join(OUTSIDE_LIBRARY_EFFECTS)}")
    return _generate(seed, "outside_library", excitation, duration_s, rate_hz, [(effect, None, magnitude_class)])


# ------------------------------------------------------------------------------------------------ suites ------
# Seeds: consecutive runs from arbitrary bases, never the product's 0-3; each entry fixes the excitation so that
# every design is covered.

IDENTIFICATION_SUITE = [(4101 + i, IDENTIFICATION_KINDS[i % 6]) for i in range(12)]      # default test run
IDENTIFICATION_SLOW_SUITE = [(4201 + i, IDENTIFICATION_KINDS[i % 6]) for i in range(60)]
IDENTIFICATION_SUITE_SEEDS = [s for s, _ in IDENTIFICATION_SUITE]
DIAGNOSIS_DRIVE_SEEDS = (5101, 5102, 5103)
DIAGNOSIS_EXCITATIONS = ("default", "steps")
DIAGNOSIS_MATRIX = [(seed, effect, cls, kind, VARIANTS.get(effect, (None,))[i % len(VARIANTS.get(effect, (None,)))])
                    for i, seed in enumerate(DIAGNOSIS_DRIVE_SEEDS) for effect in LIBRARY_EFFECTS
                    for cls in CLASSES for kind in DIAGNOSIS_EXCITATIONS]
CLEAN_SUITE = [(5201 + i, DIAGNOSIS_EXCITATIONS[i % 2]) for i in range(20)]
TWO_EFFECT_SUITE_SEEDS = [5301 + i for i in range(10)]
OUTSIDE_LIBRARY_SUITE = [(5401 + i, OUTSIDE_LIBRARY_EFFECTS[i % 2]) for i in range(10)]


def weak_search(seed: int, effect: str, excitation: str = "default", duration_s: float = DEFAULT_DURATION_S,
                variant: str | None = None, rate_hz: float | None = None) -> tuple[float, float, int]:
    """The weak magnitude of ``effect`` in case ``seed``: (magnitude, its signal [rad], simulations the search
    used). Cached, like the clean run of each case."""
    return _weak(seed, excitation, duration_s, rate_hz, effect, variant)


def clear_caches() -> None:
    """Forget the cached clean runs and weak magnitudes (e.g. to time a cold start)."""
    _context.cache_clear()
    _weak.cache_clear()
