"""Logged drive data in memory (``DriveLog``), and reading / writing it.

The file format is physics.md section 4: a CSV with a header row and the columns ``time_s, motor_torque_Nm,
motor_pos_rad, load_pos_rad`` (SI; ``load_pos_rad`` may be absent), plus a JSON sidecar with the known drive data
(same stem ``.json``, or ``meta.json`` beside it): ``r, J_m_kgm2, f_m_Nm, arm_length_m, encoder_counts_per_rev,
sample_rate_hz``. Parquet files with the same columns are read too.

Torque time stamps (one convention everywhere: ``identify``, ``diagnose``, ``synthetic_log``, ``hdrive demo``):
``motor_torque_Nm[k]`` is the torque held over [time_s[k], time_s[k+1]) (zero-order hold, stamped at the start of
the step it acts over), and the positions of row k are measured at time_s[k], before that torque acts. A log that
stamps each torque at the end of its step must be shifted by one row before it is read.

``read_log`` checks everything it reads and raises ``LogError`` naming the file, the column and the 1-based data
row (row 1 is the first line after the header). It never drops or repairs a row. Optional sidecar keys:
``units`` (column -> unit; only the column's SI unit is accepted), and ``kind`` / ``meta_extra`` as written by
``write_log`` (so that a ``DriveLog`` round-trips).
"""
from __future__ import annotations

import dataclasses
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, NamedTuple

import numpy as np
import pandas as pd

from ..common.output import atomic_write

COLUMNS = ("time_s", "motor_torque_Nm", "motor_pos_rad", "load_pos_rad")
META_KEYS = ("r", "J_m_kgm2", "f_m_Nm", "arm_length_m", "encoder_counts_per_rev", "sample_rate_hz")
REQUIRED_COLUMNS = COLUMNS[:3]
MIN_SAMPLES = 10
TIME_TOLERANCE = 0.01            # allowed relative deviation of a sample interval (from the median and 1/rate)
RATE_TOLERANCE = 1e-4            # allowed relative difference of the sidecar's rate and the time column's
PARQUET_SUFFIXES = (".parquet", ".pq")
SI_UNITS = {   # DriveLog.kind -> column -> its SI unit (the only unit a sidecar may declare for it)
    "rotary": {"time_s": "s", "motor_torque_Nm": "N.m", "motor_pos_rad": "rad", "load_pos_rad": "rad"},
    "linear": {"time_s": "s", "motor_torque_Nm": "N", "motor_pos_rad": "m", "load_pos_rad": "m"},
}
UNIT_SPELLINGS = {"N.m": ("N.m", "N m", "Nm", "N*m", "N·m")}   # accepted ways of writing a unit


class LogError(ValueError):
    """A log cannot be used: the message names the file, column, row and what is wrong."""


@dataclass
class LogMeta:
    """Known drive data that comes with a log (SI)."""

    r: float                       # gear ratio q_l / q_m (rotary drives); 1 for a direct (linear) axis
    J_m_kgm2: float | None         # motor-side inertia, when known
    f_m_Nm: float | None           # motor-side Coulomb friction, when known
    arm_length_m: float            # arm length (rotary); 1 for a linear axis (positions already in metres)
    encoder_counts_per_rev: int | None
    sample_rate_hz: float

    def to_dict(self) -> dict[str, Any]:
        """The sidecar keys (``META_KEYS``) and their values, as plain Python numbers."""
        return {k: v.item() if isinstance(v, np.generic) else v for k, v in dataclasses.asdict(self).items()}


@dataclass
class DriveLog:
    """One log, in memory. Arrays share one length; time is strictly increasing and regular;
    ``motor_torque_Nm[k]`` acts over [time_s[k], time_s[k+1]) (the module docstring's convention).

    ``kind`` is ``"rotary"`` (angles in rad, torques in N m) or ``"linear"`` (a linear axis such as the EMPS
    benchmark: positions in m, forces in N, stored in the same fields). ``extra`` holds further signals a loader
    knows about (e.g. the EMPS position reference ``qg``), ``meta_extra`` further constants (controller gains).
    """

    time_s: np.ndarray
    motor_torque_Nm: np.ndarray
    motor_pos_rad: np.ndarray
    load_pos_rad: np.ndarray | None
    meta: LogMeta
    source: str = "<memory>"
    kind: Literal["rotary", "linear"] = "rotary"
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    meta_extra: dict[str, float] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.time_s.size)

    @property
    def dt(self) -> float:
        return 1.0 / self.meta.sample_rate_hz

    @property
    def has_load(self) -> bool:
        return self.load_pos_rad is not None

    def to_frame(self) -> pd.DataFrame:
        cols = {"time_s": self.time_s, "motor_torque_Nm": self.motor_torque_Nm, "motor_pos_rad": self.motor_pos_rad}
        if self.load_pos_rad is not None:
            cols["load_pos_rad"] = self.load_pos_rad
        cols.update(self.extra)
        return pd.DataFrame(cols)

    def window(self, start: int, stop: int) -> "DriveLog":
        """Samples [start, stop) as a new log (arrays are views)."""
        s = slice(start, stop)
        return DriveLog(self.time_s[s], self.motor_torque_Nm[s], self.motor_pos_rad[s],
                        None if self.load_pos_rad is None else self.load_pos_rad[s], self.meta, self.source,
                        self.kind, {k: v[s] for k, v in self.extra.items()}, dict(self.meta_extra))


# ---------------------------------------------------------------------------------------------------- reading

def read_log(path: str | Path, meta: str | Path | dict | None = None) -> DriveLog:
    """Read a log (CSV, or Parquet for ``.parquet``/``.pq``) and its JSON sidecar, checking both.

    ``meta`` is the sidecar: a path, or the parsed dict itself. When it is None the sidecar is ``<stem>.json`` beside
    the log, or else ``meta.json`` in the same folder. Raises ``LogError`` for anything unusable.
    """
    path = Path(path)
    frame = _read_table(path)
    info, kind, meta_extra = _load_meta(path, meta)
    columns = _numeric_columns(frame, str(path))
    _check_time(columns["time_s"], info.sample_rate_hz, str(path))
    return DriveLog(columns["time_s"], columns["motor_torque_Nm"], columns["motor_pos_rad"],
                    columns.get("load_pos_rad"), info, source=str(path), kind=kind, meta_extra=meta_extra)


def _is_parquet(path: Path) -> bool:
    return path.suffix.lower() in PARQUET_SUFFIXES


def _read_table(path: Path) -> pd.DataFrame:
    """The raw table: numbers as stored (Parquet) or every CSV cell as text, so that bad cells can be quoted."""
    if not path.exists():
        raise LogError(f"{path}: log file not found")
    if not path.is_file():
        raise LogError(f"{path}: not a file")
    if path.stat().st_size == 0:
        raise LogError(f"{path}: empty file")
    try:
        if _is_parquet(path):
            frame = pd.read_parquet(path)
        else:
            frame = pd.read_csv(path, dtype=str, na_filter=False, skipinitialspace=True)
    except pd.errors.EmptyDataError:
        raise LogError(f"{path}: empty file (no header row)") from None
    except Exception as exc:  # other parser errors: keep pandas' / pyarrow's text
        raise LogError(f"{path}: cannot read the table: {_parser_message(exc)}") from exc
    frame.columns = [str(c).strip() for c in frame.columns]
    return frame


def _parser_message(exc: Exception) -> str:
    """pandas' text, with a ragged CSV line also given as a data row (e.g. a decimal comma adds a field)."""
    text = str(exc).strip()
    ragged = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", text)
    if ragged:
        want, line, got = map(int, ragged.groups())
        return f"row {line - 1} (file line {line}) has {got} fields, the header has {want}"
    return text


def _numeric_columns(frame: pd.DataFrame, where: str) -> dict[str, np.ndarray]:
    """The known columns of ``frame`` as float arrays (others are ignored); at least ``MIN_SAMPLES`` rows."""
    missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
    if missing:
        raise LogError(f"{where}: missing required column(s) {', '.join(missing)}; "
                       f"found: {', '.join(map(str, frame.columns)) or '(none)'}")
    duplicated = [c for c in COLUMNS if f"{c}.1" in frame.columns]   # pandas renames a repeated header X to X.1
    if duplicated:
        raise LogError(f"{where}: column {duplicated[0]} appears more than once in the header; keep one")
    if len(frame) < MIN_SAMPLES:
        raise LogError(f"{where}: too few samples: {len(frame)} data row(s), need at least {MIN_SAMPLES}")
    columns = {c: _numeric(frame[c], c, where) for c in COLUMNS if c in frame.columns}
    for name, limit in _plant_limits().items():
        if name in columns:
            _check_magnitude(columns[name], name, limit, where)
    return columns


def _plant_limits() -> dict[str, float]:
    """Largest magnitude the plant FMU accepts for each signal column (its variable table: the input's range and the
    initial angles' range): a larger value cannot be a measurement of this kind of drive, and would only overflow a
    simulation later without naming the row."""
    from fmu_build import variables as V

    angle = V.BY_NAME["q_m_start"].hi
    return {"motor_torque_Nm": V.BY_NAME["motor_torque"].hi, "motor_pos_rad": angle, "load_pos_rad": angle}


def _check_magnitude(values: np.ndarray, name: str, limit: float, where: str) -> None:
    bad = np.flatnonzero(np.abs(values) > limit)
    if bad.size:
        i = int(bad[0])
        raise LogError(f"{where}: column {name}, row {i + 1}: {values[i]:g} is outside the range the plant accepts "
                       f"[{-limit:g}, {limit:g}] ({bad.size} such cell(s) in this column)")


def _numeric(col: pd.Series, name: str, where: str) -> np.ndarray:
    """``col`` as float64; every cell must be a finite number, else LogError quoting the first bad cell.

    Each number is the double nearest its decimal text (Python's ``float``): pandas' own parser finds the bad
    cells, but before pandas 3 it is off by an ulp in most cells (measured: 49,879 of 50,001 load readings of a
    log), and a stick-slip fit can follow a different path on numbers an ulp apart."""
    numeric = col.dtype.kind in "iuf"
    if numeric:
        values = col.to_numpy(dtype=float)
    else:
        text = col.astype("string").fillna("")
        values = pd.to_numeric(text, errors="coerce").to_numpy(dtype=float, na_value=np.nan)
        ok = np.isfinite(values)
        values[ok] = text.to_numpy(dtype=object)[ok].astype(float)
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        i = int(bad[0])
        raw = str(values[i]) if numeric else str(text.iat[i])
        raise LogError(f"{where}: column {name}, row {i + 1}: {_describe_cell(values[i], raw)} "
                       f"({bad.size} bad cell(s) in this column)")
    return values


def _describe_cell(value: float, raw: str) -> str:
    """What is wrong with a cell whose parsed value is not finite."""
    if np.isinf(value):
        return f"infinite value {raw!r}"
    if raw.strip() == "":
        return "empty cell"
    if raw.strip().lstrip("+-").lower() == "nan":
        return f"NaN ({raw!r})"
    return f"{raw!r} is not a number"


def _check_time(t: np.ndarray, rate_hz: float, where: str) -> None:
    """Time strictly increasing, every interval within ``TIME_TOLERANCE`` of the median and of 1/rate."""
    dt = np.diff(t)
    back = np.flatnonzero(dt <= 0)
    if back.size:
        k = int(back[0]) + 2   # 1-based data row of the later sample
        raise LogError(f"{where}: column time_s, row {k}: time is not strictly increasing "
                       f"({float(t[k - 1])!r} s after {float(t[k - 2])!r} s at row {k - 1})")
    median = float(np.median(dt))
    _check_interval(dt, median, "the median interval", where)
    check_sample_rate(t, rate_hz, where)
    _check_interval(dt, 1.0 / rate_hz, f"1/sample_rate_hz ({rate_hz:g} Hz)", where)


def _check_interval(dt: np.ndarray, expected: float, what: str, where: str) -> None:
    off = np.flatnonzero(np.abs(dt - expected) > TIME_TOLERANCE * expected)
    if off.size:
        k = int(off[0]) + 2
        raise LogError(f"{where}: column time_s, row {k}: irregular time: interval {dt[k - 2]:.6g} s from row "
                       f"{k - 1}, expected {expected:.6g} s ({what}) within {TIME_TOLERANCE:.0%}")


def time_column_rate(t: np.ndarray) -> float:
    """The sample rate [Hz] the time column runs at: (samples - 1) / (last - first time)."""
    return float((t.size - 1) / (t[-1] - t[0]))


def check_sample_rate(t: np.ndarray, rate_hz: float, where: str) -> float:
    """The sidecar's sample rate against the time column's (``time_column_rate``): a relative difference above
    ``RATE_TOLERANCE`` is a ``LogError`` naming both. Why so strict: the model is simulated on the sidecar's rate;
    0.8 % off moved K* and J_l* by 6-10 % with +-0.5 % intervals (issue 21), and a time column written with 9 or
    more significant digits pins the rate to far better than 1e-4. Returns the relative difference."""
    rate_t = time_column_rate(t)
    rel = abs(rate_t / rate_hz - 1.0)
    if rel > RATE_TOLERANCE:
        raise LogError(f"{where}: sample rate: the sidecar says sample_rate_hz = {rate_hz:.10g} Hz, the column time_s "
                       f"runs at {rate_t:.10g} Hz ({t.size - 1} intervals over {t[-1] - t[0]:.10g} s): relative "
                       f"difference {rel:.3g} > {RATE_TOLERANCE:g}; correct the sidecar or the time column")
    return rel


# ---------------------------------------------------------------------------------------------------- sidecar

class _Rule(NamedTuple):
    required: bool
    integer: bool
    low: float
    inclusive: bool       # value >= low allowed (else value > low)


_META_RULES = {
    "r": _Rule(True, False, 0.0, False),
    "J_m_kgm2": _Rule(False, False, 0.0, False),
    "f_m_Nm": _Rule(False, False, 0.0, False),     # > 0: the paper's groups K*, J_l*, f_l* are scaled by f_m
    "arm_length_m": _Rule(True, False, 0.0, False),
    "encoder_counts_per_rev": _Rule(False, True, 1, True),  # absent for e.g. a linear axis with a scale
    "sample_rate_hz": _Rule(True, False, 0.0, False),
}


def _load_meta(path: Path, meta: str | Path | dict | None) -> tuple[LogMeta, str, dict[str, float]]:
    """Find, read and check the sidecar of the log at ``path``: (LogMeta, kind, meta_extra)."""
    if isinstance(meta, dict):
        content, where = meta, f"meta dict given to read_log({path})"
    else:
        candidates = [Path(meta)] if meta is not None else [path.with_suffix(".json"), path.parent / "meta.json"]
        found = next((c for c in candidates if c.is_file()), None)
        looked = "looked for: " + ", ".join(map(str, candidates))
        if found is None:
            raise LogError(f"{path}: no JSON sidecar found ({looked})")
        content, where = _read_json(found), f"sidecar {found} ({looked})"
    return _parse_meta(content, where)


def read_sidecar(path: str | Path) -> LogMeta:
    """A sidecar on its own (the known drive data, e.g. for planning an experiment), checked like ``read_log``'s."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: sidecar not found")
    return _parse_meta(_read_json(path), f"sidecar {path}")[0]


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise LogError(f"{path}: cannot read the JSON sidecar: {exc}") from exc


def _parse_meta(content: Any, where: str) -> tuple[LogMeta, str, dict[str, float]]:
    """Check the sidecar's content; ``where`` names it in messages. Unknown keys are ignored."""
    if not isinstance(content, dict):
        raise LogError(f"{where}: the sidecar must be a JSON object, got {type(content).__name__}")
    values = {key: _meta_value(content, key, rule, where) for key, rule in _META_RULES.items()}
    kind = content.get("kind", "rotary")
    if kind not in SI_UNITS:
        raise LogError(f"{where}: key 'kind' = {kind!r}: use one of {', '.join(SI_UNITS)}")
    if kind == "rotary":
        _check_plant_ranges(values, content, where)
    _check_units(content.get("units"), kind, where)
    return LogMeta(**values), kind, _meta_extra(content.get("meta_extra", {}), where)


def _meta_value(content: dict, key: str, rule: _Rule, where: str) -> float | int | None:
    """One sidecar number, checked against ``rule``."""
    value = content.get(key)
    if value is None:
        if rule.required:
            raise LogError(f"{where}: missing key {key!r}" if key not in content else f"{where}: key {key!r} is null")
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise LogError(f"{where}: key {key!r} = {value!r} is not a finite number")
    if rule.integer:
        if value != int(value):
            raise LogError(f"{where}: key {key!r} = {value!r} is not an integer")
        value = int(value)
    if value < rule.low or (value == rule.low and not rule.inclusive):
        raise LogError(f"{where}: key {key!r} = {value!r} is unphysical: must be {'>=' if rule.inclusive else '>'} "
                       f"{rule.low:g}")
    return value if rule.integer else float(value)


# Sidecar key -> the FMU parameter it becomes (a rotary drive is simulated by the plant FMU, whose variable table
# holds the allowed ranges: a value outside them would only fail later, inside a fit, without naming the key).
_PLANT_PARAMETER = {"r": "r", "J_m_kgm2": "J_m", "f_m_Nm": "f_m", "arm_length_m": "arm_length",
                    "encoder_counts_per_rev": "encoder_counts_per_rev"}


def _check_plant_ranges(values: dict[str, Any], content: dict[str, Any], where: str) -> None:
    from fmu_build import variables as V

    for key, name in _PLANT_PARAMETER.items():
        var, value = V.BY_NAME[name], values.get(key)
        if value is not None and not (var.lo <= value <= var.hi):
            unit = f" {var.unit}" if var.unit not in (None, "1") else ""
            lo, hi = (f"{b}" if var.type == "Integer" else f"{b:g}" for b in (var.lo, var.hi))
            raise LogError(f"{where}: key {key!r} = {content[key]!r}{unit} is outside the range the plant accepts "
                           f"[{lo}, {hi}]{unit}")


def _check_units(units: Any, kind: str, where: str) -> None:
    """Optional ``units``: only each known column's SI unit is accepted (no scaling is ever applied)."""
    if units is None:
        return
    if not isinstance(units, dict):
        raise LogError(f"{where}: key 'units' must map column -> unit, got {units!r}")
    for column, unit in units.items():
        si = SI_UNITS[kind].get(column)
        if si is None:
            continue   # a column read_log ignores
        allowed = UNIT_SPELLINGS.get(si, (si,))
        if not isinstance(unit, str) or unit.strip() not in allowed:
            raise LogError(f"{where}: column {column} has unit {unit!r}; only {' / '.join(allowed)} is accepted "
                           "(convert the data to SI)")


def _meta_extra(extra: Any, where: str) -> dict[str, float]:
    if not isinstance(extra, dict) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in extra.values()):
        raise LogError(f"{where}: key 'meta_extra' must map names to finite numbers, got {extra!r}")
    return {str(k): float(v) for k, v in extra.items()}


# ---------------------------------------------------------------------------------------------------- writing

def write_log(log: DriveLog, path: str | Path) -> tuple[Path, Path]:
    """Write ``log`` as CSV (Parquet for ``.parquet``/``.pq``) plus its ``.json`` sidecar; return both paths.

    The log is checked first with ``read_log``'s rules, so whatever is written reads back (exactly: CSV numbers
    are written with 17 significant digits). Each file is written to a temporary file and renamed into place.
    Columns from ``log.extra`` are written too (``read_log`` ignores them). Rows are written as they are, so the
    torque convention of the module docstring carries over unchanged.
    """
    path = Path(path)
    sidecar = path.with_suffix(".json")
    if sidecar == path:
        raise ValueError(f"{path}: the log itself cannot be a .json file (that is the sidecar's name)")
    content = _sidecar_content(log)
    frame = _frame_to_write(log)
    if _is_parquet(path):
        atomic_write(path, lambda tmp: frame.to_parquet(tmp, index=False))
    else:
        atomic_write(path, lambda tmp: frame.to_csv(tmp, index=False, float_format="%.17g"))
    atomic_write(sidecar, lambda tmp: tmp.write_text(json.dumps(content, indent=2, allow_nan=False) + "\n"))
    return path, sidecar


def _frame_to_write(log: DriveLog) -> pd.DataFrame:
    """``log.to_frame()`` after the checks ``read_log`` would apply."""
    where = f"write_log({log.source})"
    clash = set(log.extra) & set(COLUMNS)
    if clash:
        raise LogError(f"{where}: extra signal(s) named like a log column: {', '.join(sorted(clash))}")
    arrays = {"time_s": log.time_s, "motor_torque_Nm": log.motor_torque_Nm, "motor_pos_rad": log.motor_pos_rad,
              "load_pos_rad": log.load_pos_rad, **log.extra}
    lengths = {name: np.size(a) for name, a in arrays.items() if a is not None}
    if len(set(lengths.values())) > 1:
        raise LogError(f"{where}: arrays of different lengths: {lengths}")
    frame = log.to_frame()
    columns = _numeric_columns(frame, where)
    _check_time(columns["time_s"], log.meta.sample_rate_hz, where)
    return frame


def _sidecar_content(log: DriveLog) -> dict[str, Any]:
    """The sidecar dict for ``log`` (checked like one read from a file)."""
    content: dict[str, Any] = {**log.meta.to_dict(), "kind": log.kind}
    content["units"] = {c: u for c, u in SI_UNITS.get(log.kind, {}).items() if c != "load_pos_rad" or log.has_load}
    if log.meta_extra:
        content["meta_extra"] = dict(log.meta_extra)
    _parse_meta(content, f"write_log({log.source}): meta")
    return content
