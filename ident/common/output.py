"""Output written atomically: a file appears whole or not at all, a report folder only once everything in it has
been written. A failed or interrupted run never leaves a report that looks finished, nor its staging files."""
from __future__ import annotations

import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator


class OutputDirError(ValueError):
    """An output folder that cannot be written: the message names the path and the reason."""


def check_output_dir(out_dir: str | Path, option: str = "--out") -> Path:
    """Check, before any work, that ``out_dir`` is (or can become) a writable folder: not an existing file, and
    its nearest existing ancestor a folder where files can be created (a probe file is made and removed there)."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise OutputDirError(f"{option} {out}: exists and is not a folder")
    base = out if out.exists() else next((a for a in out.parents if a.exists()), Path("."))
    if not base.is_dir():
        raise OutputDirError(f"{option} {out}: {base} is not a folder, so {out} cannot be created")
    try:
        fd, probe = tempfile.mkstemp(dir=base, prefix=".hdrive-probe-")
    except OSError as exc:
        raise OutputDirError(f"{option} {out}: cannot write in {base}: {exc.strerror or exc}") from None
    os.close(fd)
    os.unlink(probe)
    return out


def atomic_write(path: Path, write: Callable[[Path], object]) -> None:
    """``write`` a temporary file beside ``path``, then rename it onto ``path`` (never a half-written file)."""
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=f".tmp-{path.name}")
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextmanager
def staged_folder(out_dir: str | Path, last: str | None = None) -> Iterator[Path]:
    """Yield a staging folder beside ``out_dir``; when the block succeeds, move its files into ``out_dir`` (created),
    ``last`` (the report) after all the others, so that a report that exists is complete. On any error the staging
    folder is removed and ``out_dir`` is left as it was."""
    out = Path(out_dir)
    created = [a for a in reversed(out.parents) if not a.exists()]  # parents this call makes, outermost first
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    done = False
    try:
        yield staging
        out.mkdir(exist_ok=True)
        for name in sorted(os.listdir(staging), key=lambda n: n == last):
            os.replace(staging / name, out / name)
        done = True
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if not done:  # nothing of a failed run stays behind, not even the parent folders made for it
            for folder in reversed(created):
                try:
                    folder.rmdir()
                except OSError:
                    break
