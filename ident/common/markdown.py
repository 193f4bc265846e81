"""The one markdown table writer of every hdrive report.

Numbers are formatted where they are printed (one format spec for the table, or one per column), so a report's
tables and its prose can use the same figures. NaN and None print as empty cells, booleans as yes / no.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np
import pandas as pd


def _cell(value: Any, spec: str | None) -> str:
    if value is None:
        return ""
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else "no"
    if isinstance(value, (float, np.floating)):
        if math.isnan(value):
            return ""
        return format(value, spec) if spec else str(value)
    return str(value)


def md_table(table: pd.DataFrame | tuple[Sequence[str], Sequence[Sequence[Any]]],
             formats: str | Mapping[str, str] = ".4g", *, empty: str = "(none)") -> str:
    """``table`` (a DataFrame, or ``(header, rows)``) as a GitHub markdown table.

    ``formats``: a format spec for every float cell (default ``.4g``), or a mapping column -> spec (columns not in it
    print floats with ``.4g``). Text cells print as they are. An empty table prints ``empty``."""
    if isinstance(table, pd.DataFrame):
        header, rows = [str(c) for c in table.columns], list(table.itertuples(index=False, name=None))
    else:
        header, rows = [str(c) for c in table[0]], [tuple(r) for r in table[1]]
    if not rows:
        return empty
    specs = [formats.get(c, ".4g") if isinstance(formats, Mapping) else formats for c in header]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_cell(v, s) for v, s in zip(row, specs)) + " |" for row in rows]
    return "\n".join(lines)
