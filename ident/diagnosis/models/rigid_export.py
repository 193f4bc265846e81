"""A rigid model as an FMU: the HarmonicDrive FMU's motor body alone is a one-body drive with the library's friction.

The rigid model ``tau = M q'' + F(q') + offset`` (F: Coulomb with its asymmetry, viscous with its asymmetry,
Stribeck) is the FMU's motor equation ``J_m q_m'' = T - F_m - r tau_s`` once the load side is decoupled: the spring
at its softest (K_s = 1e-3 N.m/rad), the gear ratio at its smallest (r = 1e-6: the spring's torque on the motor,
r K_s d, is then ~1e-15 of a N.m per rad of travel), the load frictionless (f_l = 0) and at its largest inertia
(J_l = 1e6). The motor takes J_m = M, f_m = Fc, b_m = Fv, friction_asymmetry, viscous_asymmetry, stribeck_ratio,
and stribeck_velocity = v_s r (the FMU's motor uses stribeck_velocity / r). The FMU's q_m is the axis position,
motor_torque its force; its load outputs are not part of the model.

Two things the FMU cannot carry, said plainly:

- a **constant force** (the model's ``offset``, e.g. gravity on a tilted axis): when its 95 % interval excludes 0
  the export is refused with that reason (the model with an asymmetric friction has none: the asymmetry absorbs it);
- **units of a linear axis**: a linear axis (positions in m, forces in N, mass in kg) is written as the equivalent
  rotary drive with the same numbers (1 m of travel = 1 rad of q_m, 1 N = 1 N.m, M kg = M kg.m2); the equations are
  the same, the FMU's unit labels are not, and the report says so.
"""
from __future__ import annotations

from pathlib import Path

from ...fitting.logs import DriveLog
from ...model.params import DriveParams, ParameterError
from .rigid_idim import Z95, RigidModelFit

DECOUPLED_LOAD = {"K_s": 1e-3, "r": 1e-6, "J_l": 1e6, "f_l": 0.0}


def one_body_drive(fit: RigidModelFit, log: DriveLog) -> DriveParams:
    """The HarmonicDrive parameters of the rigid model ``fit`` (see the module docstring)."""
    p = fit.params()
    counts = log.meta.encoder_counts_per_rev or 1
    return DriveParams(J_m=p["M"], f_m=p["Fc"], b_m=p.get("Fv", 0.0), friction_asymmetry=p.get("friction_asymmetry", 0.0),
                       viscous_asymmetry=p.get("viscous_asymmetry", 0.0), stribeck_ratio=p.get("stribeck_ratio", 0.0),
                       stribeck_velocity=p.get("stribeck_velocity", 1.0) * DECOUPLED_LOAD["r"],
                       encoder_counts_per_rev=int(counts), arm_length=1.0, **DECOUPLED_LOAD)


def export_one_body(fit: RigidModelFit, log: DriveLog, folder: Path, units: dict[str, str]) -> tuple[Path | None, str]:
    """Write the one-body drive FMU into ``folder``; (path, what it is) or (None, why it cannot be written)."""
    from ...model.export import export_fitted_fmu

    p = fit.params()
    if "offset" in fit.coords:
        i = fit.coords.index("offset")
        sd = float(fit.cov[i, i]) ** 0.5 if fit.cov is not None else float("nan")
        lo, hi = p["offset"] - Z95 * sd, p["offset"] + Z95 * sd
        if lo > 0 or hi < 0:
            return None, (f"the rigid model's constant force (offset = {p['offset']:.4g}, 95 % interval [{lo:.4g}, "
                          f"{hi:.4g}]) has no counterpart in the HarmonicDrive FMU; the fitted parameters are in "
                          "diagnosis.json")
    try:
        drive = one_body_drive(fit, log)
    except ParameterError as exc:
        return None, f"the rigid model does not fit the FMU's parameter ranges: {exc}"
    path = export_fitted_fmu(drive, folder / "HarmonicDrive_rigid_fitted.fmu")
    what = ("the HarmonicDrive FMU's motor body as the fitted one-body drive (J_m = M, f_m = Fc, b_m = Fv, "
            "friction_asymmetry, viscous_asymmetry, Stribeck; load decoupled: K_s = 1e-3, r = 1e-6, J_l = 1e6, "
            "f_l = 0); q_m is the axis position, motor_torque its force")
    if log.kind == "linear":
        what += ("; this is a linear axis: the FMU carries its numbers as the equivalent rotary drive (1 m = 1 rad, "
                 "1 N = 1 N.m, M kg = M kg.m2), the equations are the same, the FMU's unit labels are not")
    if "offset" in fit.coords:
        what += f"; the offset ({p['offset']:.3g} {units.get('offset', '')}, not significant) is left out"
    return path, what
