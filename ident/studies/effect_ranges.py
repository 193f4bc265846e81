"""Plausible magnitudes of the effect library's terms, each bounded by a published source the report cites.

A search over the effects (``ident.studies.paper_search``) may only use magnitudes that a real drive can have.
``EFFECT_RANGES`` gives, for every effect of ``ident.model.effects`` that the two-inertia plant can carry, its *knobs*
(the quantities a source states, in the source's own units: static/Coulomb ratio, hysteresis loss in arcmin,
kinematic error in arcsec, ...), their ranges, the source, what it states, and how the range in the FMU's SI
parameters follows. ``DRIVE_KNOBS`` are the drive's own K* and J_l* (+-50 % of the given drive).

Sources (all checkable):

- Harmonic Drive AG, *CHA Hollow Shaft Units*, engineering manual 1018854 08/2018 V03, section 6.19 table 54.1/54.2
  (accuracy: transmission accuracy, hysteresis loss, lost motion) and section 6.20 tables 54.3/54.4 (torsional
  stiffness K1, K2, K3 and limit torques T1, T2); public copy:
  https://www.manualshive.com/en/manual/harmonic-drive/cha-14a-e/3973040?page=54 . Transmission accuracy is defined
  there (glossary of the 12/2015 edition, p. 83) as the sum of the largest positive and negative deviations over one
  output turn.
- C. Canudas de Wit, H. Olsson, K. J. Astrom, P. Lischinsky, "A new model for control of systems with friction",
  IEEE Trans. Automatic Control 40(3), 419-425, 1995: the simulation parameters Fc = 1 N, Fs = 1.5 N,
  vs = 0.001 m/s.
- M. Janot, M. Gautier, M. Brunot, "Data set and reference models of EMPS" (the EMPS benchmark the project
  reproduces, ``ident.studies.emps``): Fc = 20.3935 N with offset -3.1648 N, and Fc+ = 20.1440, Fc- = 20.6277 N.
- P. R. Dahl, "Solid friction damping of mechanical vibrations", AIAA Journal 14(12), 1675-1682, 1976 (the form of
  the hysteresis element, not a magnitude).

Viscous friction has no bound here from a source: no harmonic-drive figure for it was found. Its range (damping
ratio up to 5 % of the mode the body rings in, the "realistic" case of ``hdrive paper-effects``) is marked
``cited=False`` and the report says so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping

from ..model.params import DriveParams
from .emps import PAPER, PAPER_ASYM

ARCSEC = math.pi / (180 * 3600)
ARCMIN = 60 * ARCSEC

#: CHA units, gear ratio > 50 (the nominal drive is 100:1): size -> (T1, T2 [N.m], K1, K2, K3 [N.m/rad]);
#: manual 1018854 08/2018 V03, tables 54.3 / 54.4.
CHA_STIFFNESS: dict[str, tuple[float, float, float, float, float]] = {
    "CHA-14A": (2.0, 6.9, 4.7e3, 6.1e3, 7.1e3),
    "CHA-17A": (3.9, 12.0, 10e3, 14e3, 16e3),
    "CHA-20A": (7.0, 25.0, 16e3, 25e3, 29e3),
    "CHA-25A": (14.0, 48.0, 31e3, 50e3, 57e3),
    "CHA-32A": (29.0, 108.0, 67e3, 110e3, 120e3),
    "CHA-40A": (54.0, 196.0, 130e3, 200e3, 230e3),
    "CHA-50A": (108.0, 382.0, 250e3, 400e3, 440e3),
    "CHA-58A": (168.0, 598.0, 400e3, 610e3, 710e3),
}
CHA_HYSTERESIS_LOSS_ARCMIN = 1.0     # table 54.1/54.2: "< 1" for ratio > 50, every size
CHA_TRANSMISSION_ACCURACY_ARCMIN = 1.0  # table 54.1: "< 1" (CHA-14A ... 25A, ratio > 50; larger sizes 0.5 - 0.8)
LUGRE_FS_OVER_FC = 1.5 / 1.0         # Canudas de Wit et al. 1995: Fs = 1.5 N, Fc = 1 N
LUGRE_VS_M_PER_S = 0.001             # ... vs = 0.001 m/s
CONTACT_RADIUS_SPAN = 10.0           # the load's friction acts between the arm tip (L) and L / 10 (see stribeck)
VISCOUS_ZETA_MAX = 0.05              # uncited: the "realistic" damping ratio of `hdrive paper-effects`
DRIVE_SPAN = 0.5                     # K*, J_l* within +-50 % of the given drive (issue 19)


def cubic_hardening(T1: float, T2: float, K1: float, K2: float, K3: float) -> float:
    """The hardening h [1/rad²] of K_s (d + h d³) whose tangent stiffness K_s (1 + 3 h d²) rises from K1 at zero
    twist to K3 at the catalogue's twist at T2, phi2 = T1/K1 + (T2 - T1)/K2 (the catalogue's piecewise curve)."""
    phi2 = T1 / K1 + (T2 - T1) / K2
    return (K3 / K1 - 1.0) / (3.0 * phi2**2)


@dataclass(frozen=True)
class Knob:
    """One searched quantity in a source's units: ``value(u)`` maps u in [0, 1] onto [lo, hi] (log-uniformly with
    ``log``)."""

    name: str
    lo: float
    hi: float
    unit: str
    log: bool = False

    def value(self, u: float) -> float:
        u = min(max(float(u), 0.0), 1.0)
        if self.log:
            return math.exp(math.log(self.lo) + u * (math.log(self.hi) - math.log(self.lo)))
        return self.lo + u * (self.hi - self.lo)


@dataclass(frozen=True)
class EffectRange:
    """An effect of the library with its plausible knobs. ``to_fmu(knobs, drive)`` gives the FMU parameters (SI) for
    knob values on a drive (some bounds scale with the drive's K_s or J_l)."""

    effect: str
    knobs: tuple[Knob, ...]
    to_fmu: Callable[[Mapping[str, float], DriveParams], dict[str, float]]
    source: str
    states: str
    bound: str
    cited: bool = True


def _smallest_torque(f_m: float, f_l_star_min: float) -> float:
    """A tenth of the smallest load friction of the sweep: torques below it cannot change a resolution."""
    return 0.1 * f_l_star_min * f_m


def effect_ranges(base: DriveParams | None = None, f_l_star_min: float = 0.01) -> dict[str, EffectRange]:
    """The plausible ranges on drive ``base`` (nominal by default); ``f_l_star_min`` is the sweep's lowest level."""
    p = base or DriveParams()
    return {e.effect: e for e in (*_friction_ranges(p), *_gear_ranges(p, f_l_star_min))}


def _friction_ranges(p: DriveParams) -> tuple[EffectRange, ...]:
    """Viscous (uncited), Stribeck (LuGre paper) and asymmetric friction (EMPS)."""
    a_offset = abs(PAPER["offset"]) / PAPER["Fc"]
    a_fit = abs(PAPER_ASYM["Fc_pos"] - PAPER_ASYM["Fc_neg"]) / (PAPER_ASYM["Fc_pos"] + PAPER_ASYM["Fc_neg"])
    vs_hi, vs_lo = LUGRE_VS_M_PER_S / (p.arm_length / CONTACT_RADIUS_SPAN), LUGRE_VS_M_PER_S / p.arm_length
    return (
        EffectRange("viscous_motor", (Knob("zeta_motor", 0.0, VISCOUS_ZETA_MAX, "1"),),
                    lambda k, d: {"b_m": 2 * k["zeta_motor"] * math.sqrt(d.r**2 * d.K_s * d.J_m)},
                    "none found", "-",
                    f"damping ratio up to {VISCOUS_ZETA_MAX:.0%} of the motor's ringing against the spring, "
                    "b_m = 2 zeta sqrt(r² K_s J_m) (the realistic case of `hdrive paper-effects`)", cited=False),
        EffectRange("viscous_load", (Knob("zeta_load", 0.0, VISCOUS_ZETA_MAX, "1"),),
                    lambda k, d: {"b_l": 2 * k["zeta_load"] * math.sqrt(d.K_s * d.J_l)},
                    "none found", "-",
                    f"damping ratio up to {VISCOUS_ZETA_MAX:.0%} of the load's ringing, b_l = 2 zeta sqrt(K_s J_l)",
                    cited=False),
        EffectRange("stribeck", (Knob("static_over_coulomb", 1.0, LUGRE_FS_OVER_FC, "1"),
                                 Knob("stribeck_velocity", vs_lo, vs_hi, "rad/s", log=True)),
                    lambda k, d: {"stribeck_ratio": k["static_over_coulomb"] - 1.0,
                                  "stribeck_velocity": k["stribeck_velocity"]},
                    "Canudas de Wit, Olsson, Astrom, Lischinsky 1995 (IEEE TAC 40(3))",
                    f"Fs / Fc = {LUGRE_FS_OVER_FC:g}, vs = {LUGRE_VS_M_PER_S:g} m/s",
                    f"static / Coulomb from 1 to {LUGRE_FS_OVER_FC:g} (stribeck_ratio 0 ... "
                    f"{LUGRE_FS_OVER_FC - 1:g}); vs = {LUGRE_VS_M_PER_S * 1e3:g} mm/s of sliding at a contact "
                    f"between the arm tip (L = {p.arm_length:g} m, where the paper's wedge loads the arm) and "
                    f"L/{CONTACT_RADIUS_SPAN:g}: {vs_lo:.3g} ... {vs_hi:.3g} rad/s at the load"),
        EffectRange("asymmetric_friction", (Knob("friction_asymmetry", -a_offset, a_offset, "1"),),
                    lambda k, d: {"friction_asymmetry": k["friction_asymmetry"]},
                    "Janot, Gautier, Brunot, EMPS data set and reference models",
                    f"Fc = {PAPER['Fc']:g} N with offset {PAPER['offset']:g} N; asymmetric fit Fc+ = "
                    f"{PAPER_ASYM['Fc_pos']:g} N, Fc- = {PAPER_ASYM['Fc_neg']:g} N",
                    f"|a| up to |offset| / Fc = {a_offset:.3f} (a constant offset shifts the static band like an "
                    f"asymmetry; the direct asymmetric fit gives {a_fit:.3f}); a real drive, but a ball-screw axis, "
                    "not a harmonic drive"),
    )


def _gear_ranges(p: DriveParams, f_l_star_min: float) -> tuple[EffectRange, ...]:
    """Hardening, hysteresis and kinematic error from the Harmonic Drive CHA catalogue."""
    h_rows = {size: cubic_hardening(*row) for size, row in CHA_STIFFNESS.items()}
    h_size = max(h_rows, key=h_rows.get)
    h_min = _smallest_torque(p.f_m, f_l_star_min)
    w_min_arcmin = 2 * h_min / (p.K_s * (1 + DRIVE_SPAN)) / ARCMIN
    cha = "Harmonic Drive AG, CHA manual 1018854 08/2018 V03"
    ratios = ", ".join(f"{r[4] / r[2]:.2f}" for r in CHA_STIFFNESS.values())
    return (
        EffectRange("hardening", (Knob("hardening", 0.0, h_rows[h_size], "1/rad2"),),
                    lambda k, d: {"hardening": k["hardening"]},
                    f"{cha}, tables 54.3/54.4 (ratio > 50)",
                    f"K1 ... K3 and T1, T2 per size; K3/K1 = {ratios} (CHA-14A ... 58A)",
                    f"a cubic K_s (d + h d³) whose tangent stiffness rises from K1 to K3 at the catalogue's twist at "
                    f"T2: h = (K3/K1 - 1) / (3 phi2²), largest for {h_size}: {h_rows[h_size]:.3g} /rad²"),
        EffectRange("hysteresis", (Knob("hysteresis_loss", w_min_arcmin, CHA_HYSTERESIS_LOSS_ARCMIN, "arcmin",
                                        log=True),
                                   Knob("sigma_over_K_s", 0.1, 10.0, "1", log=True)),
                    lambda k, d: {"hysteresis_torque": 0.5 * d.K_s * k["hysteresis_loss"] * ARCMIN,
                                  "hysteresis_stiffness": k["sigma_over_K_s"] * d.K_s},
                    f"{cha}, tables 54.1/54.2; Dahl 1976 for the element",
                    f"hysteresis loss < {CHA_HYSTERESIS_LOSS_ARCMIN:g} arcmin (ratio > 50, every size)",
                    "the Dahl element saturated at +-H beside the spring opens a loop 2H/K_s wide at zero torque: "
                    f"H = K_s loss / 2, loss from {w_min_arcmin:.2g} arcmin (H a tenth of the smallest load "
                    f"friction, {h_min:.2g} N.m) to {CHA_HYSTERESIS_LOSS_ARCMIN:g} arcmin; the element's stiffness "
                    "sigma has no catalogue figure: 0.1 ... 10 K_s (the library's fit range), log-uniform"),
        EffectRange("kinematic_error", (Knob("kinematic_error", 0.0, 0.5 * CHA_TRANSMISSION_ACCURACY_ARCMIN * 60,
                                             "arcsec"),
                                        Knob("kinematic_error_phase", 0.0, 2 * math.pi, "rad")),
                    lambda k, d: {"kinematic_error": k["kinematic_error"] * ARCSEC,
                                  "kinematic_error_phase": k["kinematic_error_phase"]},
                    f"{cha}, table 54.1 (ratio > 50)",
                    f"transmission accuracy < {CHA_TRANSMISSION_ACCURACY_ARCMIN:g} arcmin, peak to peak over an "
                    "output turn",
                    "the twice-per-turn error A sin(2 q_m + phi) is at most half the peak-to-peak accuracy: A up to "
                    f"{0.5 * CHA_TRANSMISSION_ACCURACY_ARCMIN * 60:g} arcsec, any phase"),
    )


def drive_knobs(span: float = DRIVE_SPAN) -> tuple[Knob, ...]:
    """The drive's own K* and J_l*, as factors 1 - span ... 1 + span of the given drive's."""
    if not 0.0 <= span < 1.0:
        raise ValueError(f"drive span = {span!r}: K* and J_l* factors 1 +- span need 0 <= span < 1")
    return (Knob("K_star_rel", 1 - span, 1 + span, "1"), Knob("J_l_star_rel", 1 - span, 1 + span, "1"))


DRIVE_KNOBS: tuple[Knob, ...] = drive_knobs()

__all__ = ["ARCMIN", "ARCSEC", "CHA_STIFFNESS", "DRIVE_KNOBS", "DRIVE_SPAN", "EffectRange", "Knob",
           "cubic_hardening", "drive_knobs", "effect_ranges"]
