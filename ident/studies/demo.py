"""The current main job: the nominal drive's response to a train of 1 ms torque pulses (CSV + PNG).

Each pulse is tau* = amplitude_star (motor torque amplitude_star * f_m) for 1 ms, followed by zero torque until
both bodies stick; the table samples every communication step of ``dt`` seconds, the plot shows the arm tip and
the motor encoder.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import pandas as pd
from tqdm import tqdm

from ..common.plotting import figure, save
from ..model.params import DriveParams
from ..model.plant import COLUMN_UNITS, Plant, Sample


@dataclass
class PulseTrainResult:
    """Samples of a pulse train and the arm increment of every pulse (between rests)."""

    samples: pd.DataFrame
    increments_um: list[float]
    params: DriveParams
    amplitude_star: float
    width_s: float

    def to_frame(self) -> pd.DataFrame:
        return self.samples

    def plot(self, path: str | Path) -> Path:
        df = self.samples
        fig, (ax1, ax2, ax3) = figure(3, 1, size=(9, 8), sharex=True)
        ax1.step(df["time_s"], df["motor_torque_Nm"] * 1e3, where="post")
        ax1.set_ylabel("motor torque [mN m]")
        ax2.plot(df["time_s"], df["arm_position_m"] * 1e6, label="arm tip")
        ax2.set_ylabel("arm position [µm]")
        ax3.step(df["time_s"], df["encoder_count"], where="post", color="C2")
        ax3.set_ylabel("motor encoder [counts]")
        ax3.set_xlabel("time [s]")
        fig.suptitle(f"Nominal drive, {len(self.increments_um)} pulses of tau* = {self.amplitude_star:g} "
                     f"for {self.width_s * 1e3:g} ms (f_l* = {self.params.f_l_star:g})")
        return save(fig, path)


def pulse_train(params: DriveParams | None = None, *, amplitude_star: float = 3.0, width_s: float = 1e-3,
                pulses: int = 10, dt: float = 1e-3, progress: bool = False) -> PulseTrainResult:
    """Apply ``pulses`` torque pulses from rest, each followed by a rest, and record everything."""
    params = params or DriveParams()
    if pulses < 1:
        raise ValueError(f"pulses must be >= 1, got {pulses}")
    if not (width_s > 0 and dt > 0):
        raise ValueError("width_s and dt must be > 0 s")
    torque = amplitude_star * params.f_m
    rows, increments = [], []
    with Plant(params) as plant:
        rows.append((*plant.sample(), 0.0))
        for _ in tqdm(range(pulses), desc="pulses", disable=not progress):
            q0 = plant.sample().arm_position
            s = plant.step(torque, width_s)
            rows.append((*s, torque))
            while not s.at_rest:
                s = plant.step(0.0, dt)
                rows.append((*s, 0.0))
            increments.append((s.arm_position - q0) * 1e6)
    samples = pd.DataFrame(rows, columns=[*Sample._fields, "motor_torque"]).rename(columns=COLUMN_UNITS)
    return PulseTrainResult(samples, increments, params, amplitude_star, width_s)


def write_demo(out_dir: str | Path, **kw) -> dict:
    """Run the pulse train and write ``pulse_train.csv``, ``pulse_train.png`` and ``summary.json``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = pulse_train(**kw)
    csv = out / "pulse_train.csv"
    tmp = csv.with_suffix(".csv.tmp")
    result.samples.to_csv(tmp, index=False)
    tmp.replace(csv)
    png = result.plot(out / "pulse_train.png")
    summary = {"csv": str(csv), "png": str(png), "increments_um": result.increments_um,
               "amplitude_star": result.amplitude_star, "width_s": result.width_s, "params": result.params.to_dict()}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return summary
