"""The independent references' results, kept on disk between test runs.

The references (the log generator's adaptive DOP853 with located events, the event-driven integrator of the base
model, the FMU-effects tests' SciPy integrator of every effect) are slow by design: plain Python and SciPy at
tolerances far below the product's. On the 2-core machine of ``bench/README.md`` they are about 220 s of the default
run's 860 s of test time. They are also pure functions of their arguments, their own source and the numerical
libraries, so a result made once is the result: ``stored`` keeps each call's result under
``$HDRIVE_CACHE/reference-results`` (the root of the FMU builds' cache: else ``$XDG_CACHE_HOME/hdrive``, else
``~/.cache/hdrive``), named by a hash of

* the function's module and name, and its arguments (pickled: ints, floats to the bit, strings, arrays, dataclasses);
* the source of every file of ``tests/reference`` and of the function's own file;
* the Python, NumPy and SciPy versions.

Any change of those makes a new entry, so a stored result is never one the code at hand would not make. A fresh
machine pays the references in full; a warm one reads them. An entry that cannot be read (damaged, or made by another
pickle) is made again; a cache folder that cannot be written is no error (the result is just not kept).
``HDRIVE_REFERENCE_CACHE=0`` turns the store off: a cold measurement, or a check that the references still run.

The store stays below ``STORE_BYTES``: every change of the references' code makes a new set of entries and leaves the
old set unread, so an unbounded store only grew (634 MB on a developer's machine after some weeks; the default run's
own references are about 70 MB, a 10 s log at 5 kHz about 2.4 MB). A read renews an entry's modification time; a new
entry that takes the store over its bound drops the entries used least recently until it holds three quarters of it.
What is kept decides only how fast a reference comes back, never what it is. The folder can be deleted at any time.
"""
from __future__ import annotations

import functools
import hashlib
import inspect
import os
import pickle
import platform
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import scipy

F = TypeVar("F", bound=Callable[..., Any])

REFERENCE_DIR = Path(__file__).resolve().parent
REPO = REFERENCE_DIR.parents[1]
#: the store's bound: room for the default run's references (about 70 MB), the benchmarks' and a few older sets
STORE_BYTES = 1024 * 2 ** 20


def cache_root() -> Path:
    """``$HDRIVE_CACHE``, else ``$XDG_CACHE_HOME/hdrive``, else ``~/.cache/hdrive``: the FMU builds' rule
    (``fmu_build.cache.cache_dir``), written again because the references import nothing of the product
    (``test_generator_imports_nothing_of_the_product``); ``test_reference_store.py`` holds the two equal."""
    root = os.environ.get("HDRIVE_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "hdrive")
    return Path(root)


@functools.lru_cache(maxsize=None)
def reference_version(extra_file: str = "") -> str:
    """A hash of the source of every file of ``tests/reference`` but this one (and of ``extra_file``, if given) and
    of the Python, NumPy and SciPy versions: what a reference's result depends on besides its arguments. This file
    only keeps results (a change to how it keeps them makes none of them another), so it is left out. Files are
    named relative to the repository, so every clone of the same code shares the entries."""
    h = hashlib.sha256()
    own = Path(__file__).resolve()
    sources = [p for p in sorted(REFERENCE_DIR.rglob("*.py")) if p.resolve() != own]
    for path in sources + ([Path(extra_file)] if extra_file else []):
        where = path.resolve()
        h.update((where.relative_to(REPO).as_posix() if where.is_relative_to(REPO) else where.name).encode())
        h.update(path.read_bytes())
    h.update(f"{platform.python_version()}|{np.__version__}|{scipy.__version__}".encode())
    return h.hexdigest()


def enabled() -> bool:
    return os.environ.get("HDRIVE_REFERENCE_CACHE", "1") != "0"


def stored(fn: F) -> F:
    """``fn`` with its results kept on disk (see the module's docstring); ``fn`` must be a pure function."""
    name = f"{fn.__module__}.{fn.__qualname__}"
    source = inspect.getsourcefile(fn) or ""
    own_file = "" if Path(source).resolve().is_relative_to(REFERENCE_DIR) else source

    @functools.wraps(fn)
    def kept(*args: Any, **kwargs: Any) -> Any:
        if not enabled():
            return fn(*args, **kwargs)
        key = hashlib.sha256(reference_version(own_file).encode() + name.encode()
                             + pickle.dumps((args, sorted(kwargs.items())), protocol=4)).hexdigest()
        path = cache_root() / "reference-results" / f"{fn.__qualname__}-{key[:32]}.pkl"
        try:
            result = pickle.loads(path.read_bytes())
        except Exception:  # absent, damaged, or made by another pickle: make it again
            pass
        else:
            _renew(path)
            return result
        result = fn(*args, **kwargs)
        _write(path, result)
        return result

    return kept  # type: ignore[return-value]


def atomic_write(path: Path, write: Callable[[Any], Any]) -> None:
    """``write(binary file)`` into a temporary file beside ``path``, then renamed to it: a reader never sees half a
    file, and an interrupted write leaves none."""
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=f".tmp-{path.name}")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(name, path)
    except BaseException:
        Path(name).unlink(missing_ok=True)
        raise


def _write(path: Path, result: Any) -> None:
    """Keep ``result`` at ``path``; a folder that cannot be written is no error (the result is just not kept)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, lambda f: pickle.dump(result, f, protocol=4))
    except OSError as err:
        print(f"tests.reference.stored: not kept ({path}: {err})", file=sys.stderr)
        return
    try:
        prune(path.parent, STORE_BYTES)
    except OSError as err:  # the entry is kept; the store is only larger than its bound until the next entry
        print(f"tests.reference.stored: not pruned ({path.parent}: {err})", file=sys.stderr)


def _renew(path: Path) -> None:
    """Mark an entry as used now (``prune`` drops the entries used least recently); a store that cannot be written
    is no error."""
    try:
        os.utime(path)
    except OSError:
        pass


def prune(folder: Path, limit: int) -> None:
    """If the entries in ``folder`` hold more than ``limit`` bytes, drop those used least recently (oldest
    modification time first) until they hold three quarters of it. Test processes that prune at once only drop an
    entry twice (no error); one that reads an entry as it goes makes it again. A file being written (``atomic_write``'s
    temporary, a dot file that also ends in ``.pkl``) belongs to its writer and is left alone."""
    entries = []
    for entry in os.scandir(folder):
        if entry.name.endswith(".pkl") and not entry.name.startswith("."):
            try:
                st = entry.stat()
            except OSError:  # dropped by another process meanwhile
                continue
            entries.append((st.st_mtime_ns, st.st_size, entry.path))
    total = sum(size for _, size, _ in entries)
    if total <= limit:
        return
    for _, size, name in sorted(entries):
        if total <= 3 * limit // 4:
            break
        Path(name).unlink(missing_ok=True)
        total -= size
