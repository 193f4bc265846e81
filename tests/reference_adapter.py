"""Loader adapter: a generated reference log (``tests/reference/generator``) as the product reads it.

The generator never imports the product; this bridge is on the *test* side. It writes the log in the product's
file format (CSV + JSON sidecar) and reads it back with the product's own reader, so that every test that uses
the reference logs also exercises ``ident.io.read_log`` -- no in-memory shortcut past the file format.
"""
from __future__ import annotations

import tempfile
from pathlib import Path

from ident.io import DriveLog, read_log
from tests.reference.generator.logs import GeneratedLog


def read_back(log: GeneratedLog, directory: str | Path | None = None, stem: str = "log") -> DriveLog:
    """Write ``log`` to ``directory`` (a temporary one when None) and read it with ``ident.io.read_log``."""
    if directory is None:
        with tempfile.TemporaryDirectory(prefix="hdrive-ref-") as tmp:
            return read_back(log, tmp, stem)
    csv_path, _ = log.write(directory, stem)
    return read_log(csv_path)
