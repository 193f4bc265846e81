"""A drive's response to a train of torque pulses, written as a log (CSV + JSON sidecar) and a PNG.

Each pulse is tau* = amplitude_star (motor torque amplitude_star * f_m) for ``width_s``, followed by zero torque until
both bodies stick. The table samples every communication step of ``dt`` seconds and follows the log convention of
``ident.fitting.logs`` (the README's "Logs"): ``motor_torque_Nm[k]`` is the torque held over [time_s[k],
time_s[k+1]) (zero-order hold, stamped at the start of the step it acts over; the last row's torque acts after the
record ends and is 0). So ``read_log`` reads the CSV as it is, and simulating ``motor_torque_Nm[:-1]`` from rest
reproduces the logged positions exactly (a test holds that).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from ..common.output import staged_folder
from ..common.plotting import figure, save
from ..fitting.logs import DriveLog, LogMeta, write_log
from ..model.params import DriveParams
from ..model.plant import Plant, Sample, SettleError

# Sample field -> column of the demo's table (the log columns first, then the plant's other outputs)
COLUMNS = {"time": "time_s", "q_m": "motor_pos_rad", "q_l": "load_pos_rad", "v_m": "v_m_rad_s", "v_l": "v_l_rad_s",
           "spring_torque": "spring_torque_Nm", "arm_position": "arm_position_m", "encoder_count": "encoder_count",
           "motor_stuck": "motor_stuck", "load_stuck": "load_stuck"}


@dataclass
class PulseTrainResult:
    """Samples of a pulse train (the log convention: torque[k] acts over [t_k, t_k+1)) and the arm increment of
    every pulse (between rests) [m]."""

    samples: pd.DataFrame
    increments_m: list[float]
    params: DriveParams
    amplitude_star: float
    width_s: float
    dt: float

    def to_frame(self) -> pd.DataFrame:
        return self.samples

    def to_log(self) -> DriveLog:
        """The samples as a ``DriveLog`` (the plant's other outputs as extra columns)."""
        df, p = self.samples, self.params
        meta = LogMeta(r=p.r, J_m_kgm2=p.J_m, f_m_Nm=p.f_m, arm_length_m=p.arm_length,
                       encoder_counts_per_rev=p.encoder_counts_per_rev, sample_rate_hz=1.0 / self.dt)
        extra = {c: df[c].to_numpy() for c in df.columns
                 if c not in ("time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad")}
        return DriveLog(df["time_s"].to_numpy(float), df["motor_torque_Nm"].to_numpy(float),
                        df["motor_pos_rad"].to_numpy(float), df["load_pos_rad"].to_numpy(float), meta,
                        source="hdrive demo", extra=extra)

    def plot(self, path: str | Path) -> Path:
        df = self.samples
        fig, (ax1, ax2, ax3) = figure(3, 1, size=(9, 8), sharex=True)
        ax1.step(df["time_s"], df["motor_torque_Nm"] * 1e3, where="post")   # held from t_k to t_k+1
        ax1.set_ylabel("motor torque [mN m]")
        ax2.plot(df["time_s"], df["arm_position_m"] * 1e6, label="arm tip")
        ax2.set_ylabel("arm position [µm]")
        ax3.step(df["time_s"], df["encoder_count"], where="post", color="C2")
        ax3.set_ylabel("motor encoder [counts]")
        ax3.set_xlabel("time [s]")
        drive = "Nominal drive" if self.params == DriveParams() else "Drive"
        fig.suptitle(f"{drive}, {len(self.increments_m)} pulses of tau* = {self.amplitude_star:g} "
                     f"for {self.width_s * 1e3:g} ms (f_l* = {self.params.f_l_star:g})")
        return save(fig, path)


def _steps_per_pulse(width_s: float, dt: float) -> int:
    """The pulse as a whole number of communication steps (the log's time grid is regular)."""
    if not (width_s > 0 and dt > 0):
        raise ValueError(f"width_s = {width_s!r} s and dt = {dt!r} s must be > 0")
    n = round(width_s / dt)
    if n < 1 or not math.isclose(n * dt, width_s, rel_tol=1e-9):
        raise ValueError(f"width_s = {width_s!r} s must be a whole number of steps dt = {dt!r} s")
    return n


def pulse_train(params: DriveParams | None = None, *, amplitude_star: float = 3.0, width_s: float = 1e-3,
                pulses: int = 10, dt: float = 1e-3, max_rest_s: float = 60.0,
                progress: bool = False) -> PulseTrainResult:
    """Apply ``pulses`` torque pulses from rest, each followed by a rest, and record everything. ``SettleError``
    when the drive is not at rest ``max_rest_s`` (simulated) after a pulse, as ``ImpulseController`` does (e.g. a
    motor friction f_m so small that the motor never sticks)."""
    params = params or DriveParams()
    if pulses < 1:
        raise ValueError(f"pulses must be >= 1, got {pulses}")
    n_pulse = _steps_per_pulse(width_s, dt)
    torque = amplitude_star * params.f_m
    rows: list[tuple] = []
    increments = []
    with Plant(params) as plant:
        s = plant.sample()
        for _ in tqdm(range(pulses), desc="pulses", disable=not progress):
            q0 = s.arm_position
            for _ in range(n_pulse):
                rows.append((*s, torque))        # torque[k] is held over [t_k, t_k+1)
                s = plant.step(torque, dt)
            for _ in range(math.ceil(max_rest_s / dt)):
                if s.at_rest:
                    break
                rows.append((*s, 0.0))
                s = plant.step(0.0, dt)
            else:
                raise SettleError(f"the drive did not come to rest within {max_rest_s:g} s after pulse "
                                  f"{len(increments) + 1} (f_m = {params.f_m:g} N.m, f_l = {params.f_l:g} N.m)")
            increments.append(s.arm_position - q0)
        rows.append((*s, 0.0))                    # the last sample: nothing is applied after it
    samples = pd.DataFrame(rows, columns=[*Sample._fields, "motor_torque_Nm"]).rename(columns=COLUMNS)
    order = ["time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad"]
    samples = samples[order + [c for c in samples.columns if c not in order]]
    for c in ("motor_stuck", "load_stuck"):
        samples[c] = samples[c].astype(int)
    return PulseTrainResult(samples, increments, params, amplitude_star, width_s, dt)


def write_demo(out_dir: str | Path, **kw) -> dict:
    """Run the pulse train and write ``pulse_train.csv`` with its sidecar ``pulse_train.json`` (``write_log``),
    ``pulse_train.png`` and ``summary.json`` (SI keys)."""
    out = Path(out_dir)
    result = pulse_train(**kw)   # the work first: a failed run leaves no folder behind
    summary = {"csv": str(out / "pulse_train.csv"), "meta": str(out / "pulse_train.json"),
               "png": str(out / "pulse_train.png"), "increments_m": result.increments_m,
               "amplitude_star": result.amplitude_star, "width_s": result.width_s, "dt_s": result.dt,
               "torque_convention": "motor_torque_Nm[k] is held over [time_s[k], time_s[k+1])",
               "params": result.params.to_dict()}
    with staged_folder(out, last="summary.json") as stage:
        write_log(result.to_log(), stage / "pulse_train.csv")
        result.plot(stage / "pulse_train.png")
        (stage / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
