"""The text of the study report (``hdrive study``): markdown sections built from a ``Study``.

Rule of this module: a sentence that states a finding (agrees, differs, grows, settles, bounded, ...) is chosen by
the numbers it describes, with the criterion beside it; only definitions and derivations are fixed text. So on any
drive the prose and the tables say the same thing (``tests/test_study.py`` runs a second drive to hold that).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..common.markdown import md_table
from ..model.params import DriveParams
from ..protocols.transient import SETTLING_BAND, Transient, alternation
from .paper_claims import PAPER, PAPER_AUTHORS, PAPER_TITLE, growth, rounds_to
from .paper_effects import AVALANCHE_RATIO

if TYPE_CHECKING:
    from pathlib import Path

    from .paper import Study

MUCH_SMALLER = 0.1   # "x << 1": at least one order of magnitude below 1


def um(x_m: float, spec: str = ".4f") -> str:
    """A length [m] at the arm, printed in µm."""
    return f"{x_m * 1e6:{spec}} µm"


def report_markdown(study: "Study", plots: dict[str, "Path"], own_level: bool) -> str:
    """The whole report. ``plots``: the sweep's figures; ``own_level``: the sweep's f_l* = 0.1 experiment is the
    study's own impulse experiment (shown once, in section IV)."""
    return "\n".join([
        _intro_md(study), _findings_md(study), _comparison_md(study), _glossary_md(study), _drive_md(study.params),
        _linear_md(study), _impulse_md(study), _sweep_md(study, plots, own_level),
        "## Why the base model behaves this way\n", _explain_impulse_md(study), _explain_avalanche_md(study),
        _explain_linear_md(study)])


def _drive_words(p: DriveParams) -> str:
    nominal = DriveParams()
    changed = [f"{k} = {v:g}" for k, v in p.to_dict().items() if v != getattr(nominal, k)]
    return "the nominal drive" if not changed else "the nominal drive with " + ", ".join(changed) + " (SI)"


def _intro_md(study: "Study") -> str:
    p, imp, lin = study.params, study.impulse, study.linear
    authors = f" by {PAPER_AUTHORS}" if PAPER_AUTHORS else " (the copy of the paper the project holds does not name " \
                                                          "its authors)"
    return f"""# Resolution study (hdrive)

This report reproduces the resolution study of the paper *"{PAPER_TITLE}"*{authors}: the smallest step a
harmonic-drive joint with friction makes reliably under a linear (PD) controller and under an impulse controller
(sections III and IV), and how the impulse resolution changes with the load-side friction (section V).

Drive: {_drive_words(p)}. Plant: the HarmonicDrive FMU (two inertias, gear ratio, torsional spring, exact Karnopp
stick-slip friction on both sides) run through fmpy; every number below is a simulation of it. Protocol: eps1 =
{um(imp.eps1_m, 'g')}, eps2 = {imp.eps2:g}, N = {imp.n_pulses} pulses per impulse experiment, {lin.n_steps} PD
steps after {lin.warmup} warm-up steps, {len(study.sweep.f_l_star)} friction levels. The symbols are defined in
the glossary below; the model, its non-dimensional form and the protocols are written out in `docs/physics.md` of
the hdrive repository. Lengths are at the arm tip, in µm.
"""


def _findings_md(study: "Study") -> str:
    lines = ["## Findings", ""]
    for c in study.claims():
        word = {True: "agrees with", False: "differs from", None: "cannot be compared with"}[c.holds]
        lines.append(f"- {c.claim[0].upper() + c.claim[1:]}: the model gives {c.model}, which {word} the paper's "
                     f"\"{c.paper}\" (criterion: {c.criterion}).")
    lines.append("- " + _transient_sentence(study.transient()))
    return "\n".join(lines) + "\n"


def _transient_sentence(t: Transient) -> str:
    if t.settled is None:
        return f"With N = {t.n_pulses} pulses the start-up transient cannot be told from the steady state."
    if not t.settled:
        return (f"The impulse experiment has not settled within its N = {t.n_pulses} pulses (pulse {t.end_pulse} is "
                "still outside the settling band): I can't tell its steady-state max.")
    if t.max_in_transient:
        return (f"The impulse resolution (max increment, {um(t.max_m)}) is pulse {t.max_pulse} of a start-up "
                f"transient that ends after pulse {t.end_pulse}; after it the max is {um(t.steady_max_m)} (section "
                "IV says how the end is found).")
    return (f"The impulse resolution (max increment, {um(t.max_m)}, pulse {t.max_pulse}) is a steady-state figure: "
            f"the start-up transient ends after pulse {t.end_pulse}.")


def _comparison_md(study: "Study") -> str:
    return f"## Paper vs model\n\n{md_table(study.comparison())}\n"


def _glossary_md(study: "Study") -> str:
    p, imp = study.params, study.impulse
    rows = [
        ("tau*", "motor torque over the motor's Coulomb friction, T_m / f_m (a pulse's amplitude)"),
        ("A_th", f"threshold amplitude: the first tau* on a grid of {imp.tol_star:g} whose N-pulse experiment has a "
                 "median increment above eps1"),
        ("A_op", "operating amplitude A_th (1 + eps2); the resolution is measured there"),
        ("eps1", f"motion threshold: an increment counts as motion above eps1 ({um(imp.eps1_m, 'g')})"),
        ("eps2", f"margin on the threshold amplitude ({imp.eps2:g})"),
        ("N", "pulses of one impulse experiment, applied in sequence from rest with zero spring deflection"),
        ("increment", "arm motion between two rests (after a pulse, or after a set-point step)"),
        ("resolution", "the MAX increment of an experiment (the paper's definition); median, min, std beside it"),
        ("T_c", f"characteristic time sqrt(J_m / f_m) ({p.T_c * 1e3:.4g} ms)"),
        ("W, W*", f"pulse width ({imp.width_s * 1e3:g} ms) and W / T_c ({imp.width_s / p.T_c:.4g})"),
        ("K*", f"spring stiffness over motor friction, K_s / f_m [1/rad] ({p.K_star:.4g})"),
        ("J_l*", f"load inertia over motor inertia, J_l / J_m ({p.J_l_star:.4g})"),
        ("f_l*", f"load friction level, f_l / f_m ({p.f_l_star:.4g}); the sweep varies it"),
        ("r, L", f"gear ratio q_l / q_m ({p.r:g}) and arm length ({p.arm_length:g} m): arm motion = q_l L"),
        ("count", f"one motor encoder count, 2 pi / {p.encoder_counts_per_rev} rad of motor angle = "
                  f"{um(p.count_at_arm_m, '.3f')} at the arm"),
        ("k", "set-point step of the linear protocol, in encoder counts"),
        ("Kp*, Kd*", "PD gains in non-dimensional form (tau* per rad of motor angle, and per rad per unit t/T_c)"),
        ("transient", "the start-up pulses before the increments settle (section IV says how its end is found)"),
        ("R²", "coefficient of determination of a least-squares line (1: the points lie on the line)"),
    ]
    return "## Glossary\n\n" + md_table((["symbol", "meaning"], rows)) + "\n"


def _drive_md(p: DriveParams) -> str:
    rows = [("J_m", f"{p.J_m:.4g}", "kg m²"), ("f_m", f"{p.f_m:.4g}", "N m"), ("K_s", f"{p.K_s:.4g}", "N m/rad"),
            ("J_l", f"{p.J_l:.4g}", "kg m²"), ("f_l", f"{p.f_l:.4g}", "N m"), ("r", f"{p.r:g}", "-"),
            ("arm length L", f"{p.arm_length:g}", "m"),
            ("encoder counts per rev", f"{int(p.encoder_counts_per_rev)}", "counts"),
            ("T_c", f"{p.T_c * 1e3:.4g}", "ms"), ("K*", f"{p.K_star:.4g}", "1/rad"), ("J_l*", f"{p.J_l_star:.4g}", "-"),
            ("f_l*", f"{p.f_l_star:.4g}", "-"), ("one count at the arm", f"{p.count_at_arm_m * 1e6:.4g}", "µm")]
    return "## Drive\n\n" + md_table((["parameter", "value", "unit"], rows)) + "\n"


def _linear_md(study: "Study") -> str:
    lin = study.linear
    tried = ", ".join(f"k = {t['counts']}: " + ("consistent" if t["consistent"] else
                                                f"failed at step {t['steps_run']} ({um(t['failing_increment_m'])})")
                      for t in lin.tried)
    return f"""## III. Linear controller (PD on the motor encoder)

Smallest consistent step: **{lin.counts} counts**; resolution (max increment) **{um(lin.resolution_m, '.3f')}**,
median {um(lin.median_m, '.3f')}, min {um(lin.min_m, '.3f')}, std {um(lin.std_m)}
(Kp* = {lin.gains['Kp_star']:g} /rad, Kd* = {lin.gains['Kd_star']:g}, {lin.gains['rate_hz']:g} Hz, saturation
tau* = {lin.gains['saturation_star']:g}). Steps tried: {tried}.

![linear: histogram and sequence of the increments](linear.png)
"""


def _impulse_md(study: "Study") -> str:
    imp, t = study.impulse, study.transient()
    return f"""## IV. Impulse controller

Threshold amplitude A_th = **{imp.threshold_amplitude:.4f}** (tau*, resolved to {imp.tol_star:g}; the first
passing amplitude of the fine ramp, verified by the failing amplitude just below), operating amplitude
A_op = {imp.operating_amplitude:.4f}. Resolution (max increment of a fresh {imp.n_pulses}-pulse experiment at A_op)
**{um(imp.resolution_m)}**, median {um(imp.median_m)}, min {um(imp.min_m)}, std {um(imp.std_m, '.5f')}.

{_transient_md(t)}

![impulse: histogram and sequence of the increments](impulse.png)
"""


def _transient_md(t: Transient) -> str:
    how = (f"How the end is found: the last quarter of the experiment (pulses {(3 * t.n_pulses) // 4 + 1}-"
           f"{t.n_pulses}) is the reference of the steady state; the transient's size is the largest distance of an "
           "increment outside the reference's range, and a pulse is settled when its increment lies within that range "
           f"widened by {SETTLING_BAND:.0%} of the transient's size on both sides (the {SETTLING_BAND:.0%} settling "
           "criterion of control engineering)")
    if t.settled is None:
        return f"**Start-up transient.** {_transient_sentence(t)}"
    band = f"{t.band_m[0] * 1e6:.4f} - {t.band_m[1] * 1e6:.4f} µm"
    if not t.settled:
        return (f"**Start-up transient.** {_transient_sentence(t)} {how} ({band}); a steady state is trusted only "
                "when the settled pulses cover at least the second half of the experiment.")
    if t.end_pulse == 0:
        return (f"**Start-up transient.** None stands out: every increment lies within the steady range. {how}.")
    where = (f"The max increment is pulse {t.max_pulse}, inside the transient: the experiment starts from rest with "
             "zero spring deflection, and the first pulses move the arm differently until the load's stick-slip "
             f"settles. After the transient the max is **{um(t.steady_max_m)}** (median {um(t.steady_median_m)}, "
             f"min {um(t.steady_min_m)}), {1 - t.steady_max_m / t.max_m:.1%} below the resolution; the paper's "
             "definition (the max of all N pulses) keeps the transient in."
             if t.max_in_transient else
             f"The max increment (pulse {t.max_pulse}) lies after the transient, so it is also the steady-state max.")
    return (f"**Start-up transient.** The transient ends after pulse {t.end_pulse}. {where} {how} ({band}); the "
            "transient ends after the last pulse outside it.")


def _sweep_md(study: "Study", plots: dict[str, "Path"], own_level: bool) -> str:
    trend, trend_median = study.sweep.trend(), study.sweep.trend("median_um")
    cols = ["f_l_star", "threshold_amplitude", "resolution_um", "max_pulse", "transient_end_pulse", "steady_max_um",
            "median_um", "min_um", "std_um", "first_increment_um"]
    ref = study.sweep.at(0.1)
    if own_level:
        figs = (f"The histogram and sequence at f_l* = {ref.params.f_l_star:.3g} (the paper's figs. 7-8) are the "
                "drive's own experiment of section IV (`impulse.png`), not drawn twice.")
    else:
        figs = (f"![histogram and sequence at f_l* = {ref.params.f_l_star:.3g} (the paper's figs. 7-8)]"
                f"({plots['increments'].name})")
    table = study.sweep.to_frame()[cols].rename(columns=lambda c: c.replace("_um", " [µm]"))
    return f"""## V. Friction sweep

Resolution vs f_l*: least-squares line slope {trend['slope_um']:.4f} µm per unit f_l*, intercept
{trend['intercept_um']:.4f} µm, R² = {trend['r2']:.3f} (median: slope {trend_median['slope_um']:.2e} µm). The
levels are log-spaced, so the plots use a log f_l* axis. `max_pulse`: the pulse of the max; `transient_end_pulse`
and `steady_max`: the end of the start-up transient and the max after it (empty: not settled within N pulses).
Full table: `sweep.csv`.

{md_table(table, {"transient_end_pulse": ".0f", "max_pulse": ".0f"})}

{figs}

![max, median, min increment vs friction level]({plots['delta_vs_friction'].name})
![standard deviation vs friction level]({plots['std_vs_friction'].name})
"""


def _impulse_facts(study: "Study") -> dict[str, Any]:
    """The numbers the impulse explanation states (lengths in m at the arm)."""
    p, imp = study.params, study.impulse
    df = study.sweep.to_frame().sort_values("f_l_star")
    W_star = imp.width_s / p.T_c
    A = imp.operating_amplitude
    motor_m = A * (A - 1) * W_star**2 / 2 * p.r * p.arm_length
    band_m = 2 * df["f_l_star"].to_numpy() * p.f_m / p.K_s * p.arm_length   # width of +-f_l/K_s at the arm
    excess_m = (df["resolution_um"] - df["median_um"]).to_numpy() * 1e-6
    th = df["threshold_amplitude"]
    med_lo, med_hi = df["median_um"].iloc[0], df["median_um"].iloc[-1]
    return dict(W_star=W_star, A=A, spring=p.r**2 * p.K_star * W_star**2, motor_m=motor_m,
                median_vs_motor=imp.median_m / motor_m - 1 if motor_m > 0 else np.inf,
                th_min=float(th.min()), th_max=float(th.max()), th_spread=float(th.max() / th.min() - 1),
                med_lo=med_lo, med_hi=med_hi, med_change=med_hi / med_lo - 1 if med_lo > 0 else np.inf,
                band_lo=band_m.min(), band_hi=band_m.max(), within_band=int(np.sum(excess_m <= band_m)),
                n_levels=len(df), f_lo=float(df["f_l_star"].iloc[0]), f_hi=float(df["f_l_star"].iloc[-1]))


def _explain_impulse_md(study: "Study") -> str:
    f, imp = _impulse_facts(study), study.impulse
    spring = (f"{f['spring']:.3g} << 1: the spring barely acts on the motor during the pulse"
              if f["spring"] < MUCH_SMALLER else
              f"{f['spring']:.3g}, not << 1: the spring acts on the motor during the pulse, so the slide below is "
              "only a first estimate")
    share = (f"agrees with that figure to {abs(f['median_vs_motor']):.1%} (within {SETTLING_BAND:.0%}): in the long "
             "run each pulse moves the arm by the motor's share"
             if abs(f["median_vs_motor"]) <= SETTLING_BAND else
             f"differs from that figure by {f['median_vs_motor']:+.1%} (more than {SETTLING_BAND:.0%}): on this "
             "drive the arm does not simply follow the motor's share")
    stop = ("So the threshold search stops where that slide reaches eps1" if abs(f["median_vs_motor"]) <= SETTLING_BAND
            else "The threshold search stops where the median increment reaches eps1")
    th = (f"less than eps2 = {imp.eps2:.0%}: the threshold hardly depends on f_l*, it is set by eps1 and the motor's "
          "own Coulomb friction" if f["th_spread"] < imp.eps2 else
          f"more than eps2 = {imp.eps2:.0%}: the threshold depends on f_l* on this drive")
    med = (f"{f['med_change']:+.1%}, within {SETTLING_BAND:.0%}: load friction leaves the median where the motor puts "
           "it and acts only through the scatter around it" if abs(f["med_change"]) <= SETTLING_BAND else
           f"{f['med_change']:+.1%}: the median itself changes with f_l*")
    bounded = (f"at all {f['n_levels']} levels the excess of the max over the median is within that band width, "
               "a bounded effect" if f["within_band"] == f["n_levels"] else
               f"the excess of the max over the median exceeds that band width at {f['n_levels'] - f['within_band']} "
               f"of {f['n_levels']} levels, so more than the load's static band is released there")
    return f"""**Impulse control.** A pulse can move the motor only if tau* > 1 (its own breakaway level, with no spring
torque). The spring stiffness the motor sees, r² K*, times the squared pulse length W*² is {spring}. With Coulomb
friction alone the motor then slides A(A-1)W*²/2 (times r L at the arm) = {um(f['motor_m'])} at A = A_op =
{f['A']:.4f}, and stops. The median increment ({um(imp.median_m)}) {share}. {stop}: A_th =
{imp.threshold_amplitude:.4f}. Over the sweep A_th ranges {f['th_min']:.4f} -
{f['th_max']:.4f}, a spread of {f['th_spread']:.2%}, {th}. The median changes from {f['med_lo']:.4f} µm at f_l* =
{f['f_lo']:.3g} to {f['med_hi']:.4f} µm at f_l* = {f['f_hi']:.3g}, {med}. The load sticks anywhere inside its static
band +-f_l/K_s, so it can release stored deflection unevenly, and that is what can put the max above the median;
the band's width 2 f_l/K_s is {f['band_lo'] * 1e6:.3g} - {f['band_hi'] * 1e6:.3g} µm at the arm over the sweep, and {bounded}.

{_growth_paragraph(study)}
"""


def _growth_paragraph(study: "Study") -> str:
    g = growth(study.sweep)
    claim = next(c for c in study.claims() if c.key == "linear_growth")
    at = study.sweep.at(0.1)
    if g["holds"] is None:
        verdict = "With fewer than three friction levels the linear-growth criterion cannot be judged."
    else:
        verdict = (f"By the criterion ({claim.criterion}) the max {'grows' if g['holds'] else 'does not grow'} "
                   f"linearly with f_l* ({claim.model}): the base model "
                   f"{'reproduces' if g['holds'] else 'does not reproduce'} the paper's linear growth.")
    same = rounds_to(at.resolution_m * 1e6, PAPER["impulse_resolution_um"], 0.01)
    point = (f"At f_l* = {at.params.f_l_star:.3g} the resolution is {um(at.resolution_m, '.3f')}, "
             + ("which rounds to the paper's 0.30 µm." if same else "against the paper's 0.30 µm at f_l* = 0.1."))
    more = ("" if g["holds"] is not False else
            " A drive whose resolution grows linearly would need something that couples load friction into the "
            "motor's step (e.g. Stribeck friction, hysteresis in the flexspline, a hardening spring); the "
            "paper-effects study (`hdrive paper-effects --out DIR`) adds each effect of the library and reports which "
            "reproduce the paper's claims. The parameters here are not tuned to the paper's figures.")
    return verdict + " " + point + more


def _explain_avalanche_md(study: "Study") -> str:
    av = study.avalanche()
    r = study.sweep.results[int(np.argmax(study.sweep.f_l_star))]
    t = study.sweep_transients()[int(np.argmax(study.sweep.f_l_star))]
    zeros = av["leading_zero_pulses"]
    start = (f"the first {zeros} pulse(s) do not move the arm (they wind the spring until K_s d reaches f_l)"
             if zeros else "the arm moves from the first pulse on")
    first = "the first pulse that moves the arm" if av["max_pulse"] == av["first_motion_pulse"] else \
        f"{av['max_pulse'] - av['first_motion_pulse']} pulse(s) after the first motion"
    if t.settled:
        changes, n = alternation(r.increments_m, av["max_pulse"], t.end_pulse)
        alt = (f"From the max to the end of the start-up transient (pulse {t.end_pulse}) successive increments "
               + (f"alternate at every one of {n} pulses: a period-two alternation (the load stops alternately short "
                  "of and beyond its mean position inside its static band) that decays into the steady state."
                  if n and changes == n else f"change direction at {changes} of {n} pulses."))
    else:
        alt = f"The experiment at this level does not settle within its {r.n_pulses} pulses."
    verdict = "this is" if av["holds"] else "this is not"
    return f"""**High friction, first motion.** At f_l* = {av['f_l_star']:.3g} {start}. The first motion is
{av['first_motion_um']:.4f} µm (pulse {av['first_motion_pulse']}, {av['first_over_median']:.2f} x the median); the
largest increment ({av['max_over_median']:.2f} x the median) comes at pulse {av['max_pulse']}, {first}. {alt} By
the avalanche criterion (first motion > {AVALANCHE_RATIO:g} x the median) {verdict} the paper's avalanche.
"""


def _explain_linear_md(study: "Study") -> str:
    p, lin = study.params, study.linear
    band_counts = 1.0 / (lin.gains["Kp_star"] * p.count_rad)
    med_counts = lin.median_m / p.count_at_arm_m
    max_counts = lin.resolution_m / p.count_at_arm_m
    failed = [t for t in lin.tried if not t["consistent"]]
    why = ("" if not failed else
           " Smaller steps failed: " + "; ".join(
               f"at k = {t['counts']} step {t['steps_run']} moved the arm only {um(t['failing_increment_m'])}"
               for t in failed) + " (not more than eps1).")
    claim = next(c for c in study.claims() if c.key == "linear_resolution")
    paper = "as in the paper (two counts, 3 µm)" if claim.holds else "where the paper reports two counts, 3 µm"
    return f"""**Linear control.** With motor friction the PD has a dead band of f_m / (Kp* f_m) = 1/Kp* rad =
{band_counts:.1f} counts of motor angle: a set-point error inside it gives |tau*| <= 1 and cannot move the motor.
At the smallest consistent step, k = {lin.counts} count(s), the median step moves the arm {med_counts:.2f} counts
({um(lin.median_m, '.3f')}).{why} The largest increment is {um(lin.resolution_m, '.2f')} = {max_counts:.2f}
counts at the arm, {paper}.
"""
