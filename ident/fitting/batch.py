"""Many logs at once (a robot's joints, a production batch of drives): one identification per log on Dask, one
table with a row per log (issue 21, item 10).

Each task reads its own log (paths travel, not arrays), identifies it, and returns a flat row: the values,
intervals, standard deviations and identifiability of K*, J_l*, f_l*, the noise estimate, the warnings, or the error
that stopped that log (a bad log does not stop the batch).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd

from .logs import LogError, read_log
from .result import NAMES

LOG_SUFFIXES = (".csv", ".parquet", ".pq")


def collect_logs(items: list[str]) -> list[Path]:
    """The log files named by ``items``: files as given, folders expanded to their CSV / Parquet files (sorted).
    ``LogError`` for a path that does not exist or a folder without logs."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in LOG_SUFFIXES)
            if not found:
                raise LogError(f"{p}: folder holds no log files ({', '.join(LOG_SUFFIXES)})")
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise LogError(f"{p}: log file not found")
    return out


def identify_row(task: tuple[str, str | None]) -> dict[str, Any]:
    """Identify one log (``task`` = (path, sidecar or None)); a flat row of the batch table."""
    from .identify import IdentificationError, identify

    path, meta = task
    row: dict[str, Any] = {"log": path}
    try:
        fit = identify(read_log(Path(path), meta))
    except (LogError, IdentificationError) as exc:
        return {**row, "status": "error", "error": str(exc), "identifiable": False}
    row.update(status="ok", error="", identifiable=fit.identifiable)
    for name in NAMES:
        e = fit.estimates[name].to_dict()
        lo, hi = e["ci95"] if e["ci95"] is not None else (None, None)
        row.update({name: e["value"], f"{name}_ci95_lo": lo, f"{name}_ci95_hi": hi, f"{name}_std": e["std"],
                    f"{name}_identifiable": e["identifiable"], f"{name}_reason": e["reason"]})
    row.update(sigma_load_rad=fit.sigma_load_rad, residual_over_noise=fit.fit["residual_over_noise"],
               fix=fit.fix, warnings=list(fit.warnings), elapsed_s=fit.elapsed_s)
    return row


def identify_many(paths: list[Path], meta: str | None = None, *, scheduler: str | None = None,
                  workers: int | None = None, progress: bool = False) -> pd.DataFrame:
    """One row per log (``identify_row``), in the order of ``paths``, computed on Dask (local worker processes
    by default, ``scheduler`` for a cluster, ``workers=0`` serially in this process)."""
    from ..protocols.batch import run_batch

    rows = run_batch(identify_row, [(str(p), meta) for p in paths], scheduler=scheduler, workers=workers,
                     progress=progress, desc="logs identified")
    return pd.DataFrame(rows)


def write_table(table: pd.DataFrame, out_dir: str | Path) -> dict[str, str]:
    """``identify.csv`` (warnings joined by " | ") and ``identify.json`` (records) in ``out_dir``."""
    from ..common.output import atomic_write

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    flat = table.copy()
    if "warnings" in flat:
        flat["warnings"] = flat["warnings"].map(lambda w: " | ".join(w) if isinstance(w, list) else "")
    csv, js = out / "identify.csv", out / "identify.json"
    atomic_write(csv, lambda tmp: flat.to_csv(tmp, index=False))
    atomic_write(js, lambda tmp: table.to_json(tmp, orient="records", indent=2))
    return {"csv": str(csv), "json": str(js)}
