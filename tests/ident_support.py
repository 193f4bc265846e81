"""Test-side helpers for identification against the independent reference generator (``tests/reference/generator``).

The generator shares no code with the product; this module only assembles its public pieces (``Drive``, ``Effects``,
``logs.Case``, ``logs.run``, ``logs.measure``, ``GeneratedLog``) into logs with a torque schedule of our choosing (the
paper's pulse train, a designed experiment), and reads generated logs back through the product's own reader
(``ident.read_log``), so every test also exercises the file format. It also computes the Cramer-Rao bound of a log
at its truth with the product's output-error problem (the FMU at the true parameters: the bound is a property of the
model, the design and the noise, not of the estimator).
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from ident import read_log
from ident.fitting.logs import DriveLog
from tests.reference.generator import logs as gen
from tests.reference.generator import excitations as exc
from tests.reference.generator.plant import Drive, Effects, HybridPlant


def read_back(g: gen.GeneratedLog, directory: str | Path | None = None, stem: str = "log") -> DriveLog:
    """Write ``g`` in the product's file format and read it with ``ident.read_log``."""
    if directory is None:
        with tempfile.TemporaryDirectory(prefix="hdrive-ident-") as tmp:
            return read_back(g, tmp, stem)
    csv, _ = g.write(directory, stem)
    return read_log(csv)


def scheduled_log(drive: Drive, schedule_Nm: np.ndarray, rate_hz: float, noise_m: float, *, seed: int = 0,
                  offset_rad: float = 0.0, d0_fraction: float = 0.0, effects: Effects | None = None,
                  q_m0_fraction: float = 0.5) -> gen.GeneratedLog:
    """A log of ``drive`` driven by ``schedule_Nm`` (one command per sample interval), simulated by the reference
    generator, measured by its sensor model (floor-quantized encoder, white load noise ``noise_m`` at the arm,
    ``offset_rad``). Starts at rest with the deflection ``d0_fraction`` of the load's static band."""
    schedule = np.asarray(schedule_Nm, dtype=float)
    duration = schedule.size / rate_hz
    excitation = exc.Excitation("custom", {"samples": int(schedule.size)}, schedule)
    case = gen.Case(seed, drive, float(rate_hz), gen.Sensors(noise_m, offset_rad), excitation, duration)
    effects = effects or Effects()
    plant = HybridPlant(drive, effects)
    q_m0 = q_m0_fraction * drive.count_rad
    d0 = d0_fraction * drive.f_l / drive.K_s
    plant.initial_state(q_m0, d0)  # raises if the start is not a rest
    run = gen.run(case, effects, (q_m0, d0))
    time_s, encoder, load = gen.measure(case, run)
    sidecar = {"r": drive.r, "J_m_kgm2": drive.J_m, "f_m_Nm": drive.f_m, "arm_length_m": drive.arm_length,
               "encoder_counts_per_rev": drive.encoder_counts_per_rev, "sample_rate_hz": float(rate_hz)}
    truth = gen.Truth(seed=seed, scenario="scheduled", K_star=drive.K_star, J_l_star=drive.J_l_star,
                      f_l_star=drive.f_l_star, si=drive.__dict__.copy(), excitation={"kind": "custom"},
                      sample_rate_hz=float(rate_hz), duration_s=duration, noise_sigma_rad=noise_m / drive.arm_length,
                      noise_m=noise_m, offset_rad=offset_rad, initial_deflection_rad=d0, initial_motor_angle_rad=q_m0,
                      effects=effects.to_dict(), engine=run.engine)
    return gen.GeneratedLog(time_s, run.torque, encoder, load, sidecar, truth, run.q_m, run.q_l)


def paper_pulse_train(drive: Drive | None = None, *, pulses: int = 150, amplitude_star: float = 1.2,
                      spacing_s: float = 0.06, width_s: float = 1e-3, rate_hz: float = 5000.0, noise_m: float = 2e-9,
                      seed: int = 0, d0_fraction: float = 0.0) -> gen.GeneratedLog:
    """The paper's impulse experiment as a log: ``pulses`` one-way pulses of ``amplitude_star`` f_m, ``width_s``
    wide, every ``spacing_s``, after 50 ms of rest (issue 21: 150 pulses at 1.2 f_m, 60 ms apart, 5 kHz, 2 nm)."""
    drive = drive or Drive()
    lead, step, width = round(0.05 * rate_hz), round(spacing_s * rate_hz), max(1, round(width_s * rate_hz))
    tau = np.zeros(lead + pulses * step)
    for k in range(pulses):
        tau[lead + k * step: lead + k * step + width] = amplitude_star * drive.f_m
    return scheduled_log(drive, tau, rate_hz, noise_m, seed=seed, d0_fraction=d0_fraction)


def true_theta(g: gen.GeneratedLog) -> np.ndarray:
    """The product's unknowns (ln K*, ln J_l*, ln f_l*, d0 / static band) at the log's truth."""
    t = g.truth
    band = t.si["f_l"] / t.si["K_s"]
    return np.array([math.log(t.K_star), math.log(t.J_l_star), math.log(t.f_l_star),
                     t.initial_deflection_rad / band])


def cramer_rao_at_truth(log: DriveLog, g: gen.GeneratedLog) -> np.ndarray:
    """Relative (log-parameter) Cramer-Rao standard deviations of K*, J_l*, f_l* for ``log`` at its truth, with the
    true load noise."""
    from ident.fitting.identify import cramer_rao

    return cramer_rao(log, true_theta(g), g.truth.noise_sigma_rad)[:3]


def with_drive(g_drive: Drive, **changes: float) -> Drive:
    return replace(g_drive, **changes)
