"""The paper's claims about its drive as numbers: each with a target, a tolerance, the sentence it comes from, and a
metric that turns protocol results into a value, a verdict and a misfit.

The paper (its text: ``shared/docs/paper.txt``) states four things about the resolution of its drive, plus what its
experimental histogram shows:

1. ``impulse_resolution``: the impulse resolution (the MAX increment of the protocol) is 0.30 µm (section IV);
2. ``linear_over_impulse``: the linear controller's resolution (3 µm, consistent at two encoder counts) is about
   10x the impulse resolution (sections III and VI);
3. ``linear_growth``: the resolution grows linearly with the load friction level f_l* over the 25 levels
   (section V, Fig. 9): the least-squares line of the max increment vs f_l* rises and has R² >= 0.9;
4. ``avalanche``: at high friction the first motion of the arm is much larger than the later increments, which are
   then smooth (section V, Fig. 8): first motion >= 2x the median, no later increment above 2x the median;
5. ``experimental_histogram``: almost all increments of the experiment at f_l* = 0.176 are below 0.3 µm (sections
   IV and V, Figs. 6 and 11).

``ClaimInputs`` holds what the metrics need (plain arrays, so that a test can build a known sequence by hand);
``claim_values`` returns one ``ClaimValue`` per claim. A claim's *misfit* is how far the value is outside what the
claim allows, counted in the claim's ``unit`` (its tolerance, or for a bare bound the unit stated with it): 0 exactly
when the claim is met. The search (``ident.studies.paper_search``) minimises the misfits together (Pareto).

The study report (``hdrive study``) states the same claims against its one drive as *verdicts* (``Verdict``,
``study_verdicts``), to the paper's printed precision: a figure agrees when it rounds to the paper's figure (3 µm: to
1 µm; 0.30 µm: to 0.01 µm; counts equal); "more than an order of magnitude" as linear / impulse > 10; growth and
avalanche by the paper-effects study's criteria (``LINEAR_R2``, ``LINEAR_GROWTH``, ``AVALANCHE_RATIO``). The search
needs a distance rather than a yes/no, hence the tolerances above; both read their targets from ``CLAIMS``.

Lengths are µm at the arm tip, friction levels f_l* = f_l / f_m, as everywhere in ``ident.protocols``.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .paper_effects import AVALANCHE_RATIO, LINEAR_GROWTH, LINEAR_R2

if TYPE_CHECKING:
    from ..protocols.sweep import FrictionSweep

F_L_IMPULSE = 0.1        # f_l* of the paper's impulse experiment and histogram (section V: "for example ... 0.1")
F_L_EXPERIMENT = 0.176   # f_l* of the paper's experimental histogram (Fig. 11)
LINEAR_COUNTS = 2        # "all motions that occur are less two encoder counts (3um)"


@dataclass(frozen=True)
class Claim:
    """One claim of the paper as a number.

    ``sense``: ``"within"`` (met when |value - target| <= tolerance) or ``"at_least"`` (met when
    value >= target - tolerance). ``unit``: the step in which the misfit is counted (the tolerance unless the claim
    is a bare bound). ``source``: the paper's sentence(s), verbatim; ``where``: section / figure; ``basis``: how the
    number and its tolerance follow from the sentence."""

    name: str
    target: float
    tolerance: float
    sense: Literal["within", "at_least"]
    quantity: str
    source: str
    where: str
    basis: str
    unit: float = 0.0

    @property
    def step(self) -> float:
        """The misfit's unit: ``unit`` if given, else the tolerance."""
        return self.unit or self.tolerance

    @property
    def met_if(self) -> str:
        if self.sense == "within":
            return f"|value - {self.target:g}| <= {self.tolerance:g}"
        return f"value >= {self.target - self.tolerance:g}"

    def excess(self, value: float) -> float:
        """How far ``value`` lies outside what the claim allows, in units of ``step`` (0 when inside)."""
        if not math.isfinite(value):
            return math.inf
        if self.sense == "within":
            return max(0.0, abs(value - self.target) - self.tolerance) / self.step
        return max(0.0, (self.target - self.tolerance) - value) / self.step

    def to_dict(self) -> dict[str, Any]:
        return dict(name=self.name, target=self.target, tolerance=self.tolerance, sense=self.sense,
                    met_if=self.met_if, quantity=self.quantity, source=self.source, where=self.where,
                    basis=self.basis)


CLAIMS: tuple[Claim, ...] = (
    Claim("impulse_resolution", 0.30, 0.05, "within",
          f"impulse resolution (max increment of the protocol) at f_l* = {F_L_IMPULSE:g} [µm]",
          "It is evident from the histogram that almost all motion increments are less than 0.3um, so the "
          "resolution under impulse control is 0.30um.",
          "section IV, Fig. 6",
          "the sentence reads the bound off a histogram to one decimal (0.3 µm), so the value is known to its "
          "rounding, +-0.05 µm; the f_l* of the paper's simulations (section V) is the nominal 0.1"),
    Claim("linear_over_impulse", 10.0, 1.7, "within",
          f"linear resolution / impulse resolution at f_l* = {F_L_IMPULSE:g} (and the linear one consistent at "
          f"{LINEAR_COUNTS} counts)",
          "all motions that occur are less two encoder counts (3um). Therefore, the resolution of the arm for "
          "linear controller is 3um. [...] the resolution of impulse controller can be increased by more than an "
          "order of magnitude over resolution of conventional control methods.",
          "sections III and VI",
          "3 µm / 0.30 µm = 10; the impulse reading's +-0.05 µm makes it 3 / 0.35 ... 3 / 0.25 = 8.6 ... 12, i.e. "
          "+-1.7; the linear value is fixed by the count (two counts); a linear resolution at another count adds "
          "one unit of misfit per count"),
    Claim("linear_growth", 1.0, 1.0 - LINEAR_R2, "at_least",
          "R² of the least-squares line max increment = slope f_l* + intercept over the friction levels, "
          "negative when the slope is not > 0",
          "For different friction levels, the maximum delta, median delta, and minimum delta are plotted in Fig.9 "
          "which shows that the resolution gets worse proportional to the friction level. [...] the resolution is "
          "degraded linearly to the friction level.",
          "section V, Figs. 9 and 12",
          f"a straight rising line (R² = 1) within {1.0 - LINEAR_R2:.1f}: R² >= {LINEAR_R2:g} and slope > 0 over "
          "the paper's 25 levels f_l* = 0.01 ... 1 (the criterion of `hdrive paper-effects`)"),
    Claim("avalanche", AVALANCHE_RATIO, 0.0, "at_least",
          "first motion of the arm / median increment at the highest friction level (and no later increment "
          f"above {AVALANCHE_RATIO:g}x the median)",
          "when friction level is big, the arm can only move after a number of pulses are applied and the spring "
          "deformation has accumulated to a certain amount. [...] The first step of the delta is very big, and then "
          "gets smooth afterwards, as shown in Fig.8.",
          "section V, Fig. 8",
          f"'very big' as at least {AVALANCHE_RATIO:g}x the median (the criterion of `hdrive paper-effects`); "
          f"'then smooth' as no later increment above {AVALANCHE_RATIO:g}x the median; the misfit is counted in "
          "medians. Judged at the highest level, as the sentence says 'when friction level is big' (Fig. 8 itself "
          "is drawn at f_l* = 0.1)", unit=1.0),
    Claim("experimental_histogram", 1.0, 0.05, "at_least",
          f"fraction of the increments below 0.3 µm at f_l* = {F_L_EXPERIMENT:g}",
          "It is evident from the histogram that almost all motion increments are less than 0.3um [...] "
          "Fig.11 Experimental histogram for friction level f_l* = 0.176",
          "section IV (Fig. 6) and section V (Fig. 11)",
          "'almost all' read as at least 95 % (at most one increment in twenty above 0.3 µm: a reading convention, "
          f"stated here, not a number of the paper); the experiment's friction level is the one the paper names "
          f"for its experimental histogram, f_l* = {F_L_EXPERIMENT:g}"),
)

BY_NAME: dict[str, Claim] = {c.name: c for c in CLAIMS}
HIST_BOUND_UM = 0.3      # the bound of "almost all motion increments are less than 0.3um"


@dataclass
class ClaimInputs:
    """What the claims are computed from (µm at the arm).

    ``f_l_star``, ``max_um``: the sweep's levels and the max increment at each; ``impulse_um``: the increments of
    the impulse protocol at f_l* = 0.1; ``top_um``: the increments at the highest level; ``experiment_um``: the
    increments at f_l* = 0.176; ``linear_um``: the linear (PD) resolution and ``linear_counts`` its step."""

    f_l_star: np.ndarray
    max_um: np.ndarray
    impulse_um: np.ndarray
    top_um: np.ndarray
    experiment_um: np.ndarray
    linear_um: float
    linear_counts: int


@dataclass(frozen=True)
class ClaimValue:
    """A claim's value on one drive, whether it is met, its misfit (``Claim.excess`` plus any side condition) and
    the numbers behind the value."""

    value: float
    met: bool
    misfit: float
    details: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def rising_line(x: np.ndarray, y: np.ndarray) -> dict[str, float]:
    """Least-squares line y = slope x + intercept with its R²; ``signed_r2`` is R² when the slope is > 0 and -R²
    otherwise (a falling or flat line never counts as growth). A constant y has R² = 0."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 2 or np.ptp(x) == 0:
        raise ValueError("a line needs at least two distinct friction levels")
    slope, intercept = np.polyfit(x, y, 1)
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    r2 = 1.0 - float(np.sum((y - slope * x - intercept) ** 2)) / ss_tot if ss_tot > 0 else 0.0
    return dict(slope_um=float(slope), intercept_um=float(intercept), r2=r2,
                signed_r2=r2 if slope > 0 else -r2, growth=float(y[np.argmax(x)] / y[np.argmin(x)])
                if y[np.argmin(x)] > 0 else math.inf)


def avalanche_ratios(increments_um: np.ndarray) -> dict[str, float]:
    """The arm's first motion (first nonzero increment; the pulses before it only wind the spring), its pulse number,
    and the first motion and the largest later increment over the median of the whole sequence."""
    x = np.asarray(increments_um, float)
    med = float(np.median(x))
    moving = np.flatnonzero(x != 0)
    if moving.size == 0:
        return dict(first_motion_um=0.0, first_pulse=float(x.size + 1), median_um=med, first_over_median=0.0,
                    later_over_median=0.0)
    k = int(moving[0])
    later = float(x[k + 1:].max()) if k + 1 < x.size else 0.0
    ratio = (lambda a: a / med) if med > 0 else (lambda a: math.inf if a > 0 else 0.0)
    return dict(first_motion_um=float(x[k]), first_pulse=float(k + 1), median_um=med,
                first_over_median=ratio(float(x[k])), later_over_median=ratio(later))


def _verdict(claim: Claim, value: float, extra: float = 0.0, ok: bool = True, **details: float) -> ClaimValue:
    misfit = claim.excess(value) + extra
    return ClaimValue(float(value), bool(ok and misfit == 0.0 and math.isfinite(value)), misfit, details)


def claim_values(d: ClaimInputs) -> dict[str, ClaimValue]:
    """Every claim of ``CLAIMS`` on the drive described by ``d``."""
    imp = float(np.max(d.impulse_um))
    ratio = d.linear_um / imp if imp > 0 else math.inf
    line = rising_line(d.f_l_star, d.max_um)
    ava = avalanche_ratios(d.top_um)
    smooth_excess = max(0.0, ava["later_over_median"] - AVALANCHE_RATIO) / BY_NAME["avalanche"].step
    below = float(np.mean(np.asarray(d.experiment_um) < HIST_BOUND_UM))
    return {
        "impulse_resolution": _verdict(BY_NAME["impulse_resolution"], imp,
                                       median_um=float(np.median(d.impulse_um))),
        "linear_over_impulse": _verdict(BY_NAME["linear_over_impulse"], ratio, abs(d.linear_counts - LINEAR_COUNTS),
                                        linear_um=float(d.linear_um), linear_counts=float(d.linear_counts),
                                        impulse_um=imp),
        "linear_growth": _verdict(BY_NAME["linear_growth"], line["signed_r2"], slope_um=line["slope_um"],
                                  intercept_um=line["intercept_um"], r2=line["r2"], growth=line["growth"],
                                  levels=float(np.size(d.f_l_star))),
        "avalanche": _verdict(BY_NAME["avalanche"], ava["first_over_median"], smooth_excess,
                              f_l_star=float(np.max(d.f_l_star)), **ava),
        "experimental_histogram": _verdict(BY_NAME["experimental_histogram"], below,
                                           max_um=float(np.max(d.experiment_um)),
                                           median_um=float(np.median(d.experiment_um))),
    }


def claims_table() -> list[dict[str, Any]]:
    """The claims as JSON-ready records (name, target, tolerance, sense, source sentence, ...)."""
    return [c.to_dict() for c in CLAIMS]


# ---------------------------------------------------------------- the study report's verdicts -------

# What the paper reports (sections III-V and VI), for the side-by-side table.
PAPER = {
    "linear_resolution_um": 3.0,
    "linear_counts": LINEAR_COUNTS,
    "impulse_resolution_um": BY_NAME["impulse_resolution"].target,
    "ratio": BY_NAME["linear_over_impulse"].target,
}
PAPER_TITLE = "Study of Resolution for Harmonic Drives Controller with Friction in Precision Robotic System"
PAPER_AUTHORS = None   # the project's copy of the paper (text only) does not name them: not guessed


@dataclass(frozen=True)
class Verdict:
    """One claim of the paper against the study's model, to the paper's printed precision (the study report's
    side-by-side table). ``holds`` is None when the study cannot tell (e.g. one level)."""

    key: str
    claim: str
    paper: str
    model: str
    holds: bool | None
    criterion: str

    @property
    def verdict(self) -> str:
        return {True: "agrees", False: "differs", None: "can't tell"}[self.holds]


def rounds_to(value: float, paper: float, precision: float) -> bool:
    """Does ``value`` round to ``paper`` at the paper's ``precision`` (half a unit of its last digit either way)?"""
    return abs(value - paper) < precision / 2


def growth(sweep: "FrictionSweep") -> dict[str, Any]:
    """The linear-growth criterion on the sweep's max increments: slope, R^2, max(highest) / max(lowest level)."""
    df = sweep.to_frame().sort_values("f_l_star")
    t = sweep.trend()
    lo, hi = df["resolution_um"].iloc[0], df["resolution_um"].iloc[-1]
    g = float(hi / lo) if lo > 0 else math.inf
    holds = None if len(df) < 3 or not math.isfinite(t["r2"]) else \
        bool(t["slope_um"] > 0 and t["r2"] >= LINEAR_R2 and g >= LINEAR_GROWTH)
    return dict(slope_um=t["slope_um"], intercept_um=t["intercept_um"], r2=t["r2"], growth=g, holds=holds,
                f_lo=float(df["f_l_star"].iloc[0]), f_hi=float(df["f_l_star"].iloc[-1]))


def avalanche(sweep: "FrictionSweep") -> dict[str, Any]:
    """The highest-friction experiment: leading pulses without arm motion, the first motion and the max against the
    median, and the avalanche criterion (first motion > ``AVALANCHE_RATIO`` x median)."""
    r = sweep.results[int(np.argmax(sweep.f_l_star))]
    x = r.increments_m
    med = float(np.median(x))
    a = avalanche_ratios(x * 1e6)
    first_pulse = int(a["first_pulse"])
    ratio = a["first_over_median"] if med > 0 else math.inf
    return {"f_l_star": float(r.params.f_l_star), "leading_zero_pulses": first_pulse - 1,
            "first_motion_um": a["first_motion_um"], "first_motion_pulse": first_pulse, "first_over_median": ratio,
            "max_pulse": int(np.argmax(x)) + 1, "max_over_median": float(x.max() / med) if med > 0 else math.inf,
            "holds": bool(ratio > AVALANCHE_RATIO)}


def study_verdicts(linear_m: float, counts: int, impulse_m: float, sweep: "FrictionSweep") -> list[Verdict]:
    """The paper's five claims against the model's figures (linear and impulse resolution [m], the sweep)."""
    lin_um, imp_um = linear_m * 1e6, impulse_m * 1e6
    ratio = linear_m / impulse_m if impulse_m > 0 else math.inf
    g, av = growth(sweep), avalanche(sweep)
    return [
        Verdict("linear_resolution", "linear resolution (PD on the motor encoder)", "3 µm (two counts)",
              f"{lin_um:.2f} µm ({counts} counts)",
              counts == PAPER["linear_counts"] and rounds_to(lin_um, PAPER["linear_resolution_um"], 1.0),
              "same number of counts, and the max rounds to 3 µm (the paper's precision: 1 µm)"),
        Verdict("impulse_resolution", "impulse resolution", "0.30 µm", f"{imp_um:.3f} µm",
              rounds_to(imp_um, PAPER["impulse_resolution_um"], 0.01),
              "the max rounds to 0.30 µm (the paper's precision: 0.01 µm)"),
        Verdict("ratio", "linear / impulse resolution", "more than an order of magnitude (3 / 0.30 = 10)",
              f"{ratio:.1f}x", bool(ratio > PAPER["ratio"]), "ratio > 10"),
        Verdict("linear_growth", "resolution vs load friction f_l*", "grows linearly",
              f"slope {g['slope_um']:.3g} µm per unit f_l*, R² {g['r2']:.2f}, max x{g['growth']:.2f} from f_l* = "
              f"{g['f_lo']:.3g} to {g['f_hi']:.3g}", g["holds"],
              f"slope > 0, R² >= {LINEAR_R2:g} and max at the highest level >= {LINEAR_GROWTH:g} x the lowest's "
              "(as in the paper-effects study)"),
        Verdict("avalanche", "first motion at high friction", "large ('avalanche'), then smooth",
              f"at f_l* = {av['f_l_star']:.3g}: first motion {av['first_motion_um']:.3g} µm (pulse "
              f"{av['first_motion_pulse']}) = {av['first_over_median']:.2f} x median", av["holds"],
              f"first motion > {AVALANCHE_RATIO:g} x the median at the highest level (as in the paper-effects study)"),
    ]


__all__ = ["BY_NAME", "CLAIMS", "PAPER", "PAPER_AUTHORS", "PAPER_TITLE", "Claim", "ClaimInputs", "ClaimValue",
           "F_L_EXPERIMENT", "F_L_IMPULSE", "HIST_BOUND_UM", "LINEAR_COUNTS", "Verdict", "avalanche",
           "avalanche_ratios", "claim_values", "claims_table", "growth", "rising_line", "rounds_to", "study_verdicts"]
