"""The one unit convention of every JSON document hdrive prints or writes: SI, named in the key's suffix.

- A key that holds a dimensional quantity ends with its SI unit: ``_m``, ``_s``, ``_rad``, ``_rad_s``, ``_Nm``,
  ``_kgm2``, ``_Nm_per_rad``, ``_hz``, ... (``resolution_m``, ``elapsed_s``, ``load_offset_rad``).
- Drive parameters keep their FMU variable names (``J_m``, ``K_s``, ``f_l``, ``arm_length``: SI, units in the
  variable table ``fmu_build/variables.py``); non-dimensional quantities carry ``_star`` or are plain ratios and
  counts (``f_l_star``, ``threshold_amplitude`` in tau*, ``counts``, ``r2``, ``relative_error_pct``).
- Human-facing text (reports, plots, printed tables) shows lengths at the arm in µm; JSON never does.

``si_keys`` applies the convention to a result built with scaled units: every key ending in a scaled suffix
(``_um``, ``_mm``, ``_nm``, ``_ms``, ``_us``, ``_mrad``, ``_urad``, ``_mNm``) is renamed to its SI suffix and every
number below it is scaled to SI. ``non_si_keys`` lists the keys that break the convention (for tests); ``plain_json`` makes a result strict JSON
(numpy numbers as Python numbers, NaN and infinity as null).
"""
from __future__ import annotations

import math
import numbers
from typing import Any

# scaled suffix -> (SI suffix, factor to SI)
SCALED_SUFFIXES: dict[str, tuple[str, float]] = {
    "_um": ("_m", 1e-6), "_mm": ("_m", 1e-3), "_nm": ("_m", 1e-9),
    "_ms": ("_s", 1e-3), "_us": ("_s", 1e-6),
    "_mrad": ("_rad", 1e-3), "_urad": ("_rad", 1e-6),
    "_mNm": ("_Nm", 1e-3),
}


def after_number(unit: str | None) -> str:
    """What follows a number in a sentence: a space and ``unit``, or nothing for a ratio (unit "1" or none), so that
    a sentence reads "below 1.7e-08 from none", not "below 1.7e-08 1 from none"."""
    return "" if unit in (None, "", "1") else f" {unit}"


def _scaled(key: str) -> tuple[str, float] | None:
    for suffix, (si, factor) in SCALED_SUFFIXES.items():
        if key.endswith(suffix) and len(key) > len(suffix):
            return key[: -len(suffix)] + si, factor
    return None


def _scale(value: Any, factor: float) -> Any:
    """Every number in ``value`` (nested lists / dicts) times ``factor``; other values unchanged."""
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, numbers.Real):
        return float(value) * factor if math.isfinite(value) else float(value)
    if isinstance(value, dict):
        return {k: _scale(v, factor) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_scale(v, factor) for v in value]
    return value


def si_keys(value: Any) -> Any:
    """``value`` with every scaled-unit key renamed to SI and its numbers scaled (nested dicts and lists).

    A scaled key whose SI twin is already present in the same dict (e.g. ``increment_um`` beside ``increment_m``) is
    dropped: the twin already holds the quantity in SI."""
    if isinstance(value, dict):
        out: dict[str, Any] = {}
        for key, v in value.items():
            scaled = _scaled(str(key))
            if scaled is None:
                out[key] = si_keys(v)
            elif scaled[0] not in value:
                out[scaled[0]] = _scale(si_keys(v), scaled[1])
        return out
    if isinstance(value, (list, tuple)):
        return [si_keys(v) for v in value]
    return value


def plain_json(value: Any) -> Any:
    """``value`` as strict JSON data: numpy scalars and arrays as Python numbers and lists, tuples as lists, and
    NaN / infinity as None (JSON has no such numbers; ``None`` reads as "not available")."""
    if isinstance(value, dict):
        return {str(k): plain_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [plain_json(v) for v in value]
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        return plain_json(value.tolist())
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        return float(value) if math.isfinite(value) else None
    return value


def non_si_keys(value: Any, path: str = "") -> list[str]:
    """Paths (``a.b[0].c``) of the keys in ``value`` that end in a scaled unit suffix."""
    found: list[str] = []
    if isinstance(value, dict):
        for key, v in value.items():
            here = f"{path}.{key}" if path else str(key)
            if _scaled(str(key)) is not None:
                found.append(here)
            found += non_si_keys(v, here)
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            found += non_si_keys(v, f"{path}[{i}]")
    return found


__all__ = ["SCALED_SUFFIXES", "non_si_keys", "plain_json", "si_keys"]
