"""The build cache: one folder per entry, published atomically, with a checksum verified at every load.

An entry is ``<cache>/<key>/`` holding one built file (``HarmonicDrive.fmu``, ``hd_runner.so``) and beside it
``<file>.sha256``, its SHA-256 written at build time. ``cached_file`` verifies the checksum before handing the path
out, so a damaged entry (a truncated zip or shared library, a folder in place of the file, a zip whose binary was
replaced, a missing checksum) is never loaded - loading a truncated ``.so`` is what raised SIGBUS. It is rebuilt
once, with one line on stderr; a rebuilt entry that still does not verify is a ``BuildError``.

Why a folder per entry: the file and its checksum appear together through one ``os.rename`` of a staging folder, so
concurrent builders (Dask workers) never see one without the other, and the first rename wins.

A cache folder that cannot be written is replaced for the rest of the process by a temporary one (with a message),
so that work that needs a new build (a fitted drive's FMU) still runs. SIGTERM and Ctrl-C during a build leave no
staging folder, no ``hdrive-build-*`` folder and no ``.tmp`` file behind: the build runs inside ``interruptible()``.
"""
from __future__ import annotations

import atexit
import contextlib
import errno
import hashlib
import os
import shutil
import signal
import sys
import tempfile
import threading
from pathlib import Path
from typing import Callable, Iterator

_VERIFIED: dict[tuple[str, int, int, int], str] = {}  # (path, inode, size, mtime_ns) -> sha256 already checked
_FALLBACK: Path | None = None  # the temporary cache folder of this process, once the configured one was unwritable


class BuildError(RuntimeError):
    """The FMU (or the stepping loop) could not be built: no C compiler, a compile error, missing FMI headers, or a
    cache entry that is still damaged after its rebuild."""


def cache_dir() -> Path:
    """``$HDRIVE_CACHE``, else ``$XDG_CACHE_HOME/hdrive``, else ``~/.cache/hdrive``."""
    root = os.environ.get("HDRIVE_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "hdrive")
    return Path(root)


def sha256_file(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _problem(entry: Path, filename: str) -> str | None:
    """Why the entry cannot be used, or None when its file matches its checksum."""
    target, sums = entry / filename, entry / f"{filename}.sha256"
    if not target.is_file():
        return f"{filename} is a folder" if target.is_dir() else f"{filename} is missing"
    try:
        expected = sums.read_text().split()[0] if sums.is_file() else ""
        st = target.stat()
        key = (str(target), st.st_ino, st.st_size, st.st_mtime_ns)
        actual = _VERIFIED.get(key) or sha256_file(target)
    except (OSError, IndexError) as exc:
        return f"unreadable ({exc})"
    if not expected:
        return "its checksum file is missing"
    if actual != expected:
        return "its checksum does not match: truncated or modified"
    _VERIFIED[key] = actual
    return None


def _say(message: str) -> None:
    print(f"hdrive: {message}", file=sys.stderr, flush=True)


def _fallback(root: Path, reason: str) -> Path:
    """This process's temporary cache folder (created once, removed at exit), used instead of ``root``."""
    global _FALLBACK
    if _FALLBACK is None:
        _FALLBACK = Path(tempfile.mkdtemp(prefix="hdrive-cache-"))
        atexit.register(shutil.rmtree, _FALLBACK, True)
        _say(f"the build cache {root} is not writable ({reason}); building into {_FALLBACK} for this run "
             "(set HDRIVE_CACHE to a writable folder to keep the builds)")
    return _FALLBACK


def _writable_root(root: Path) -> Path:
    """``root`` if a staging folder can be made in it, else this process's temporary cache."""
    try:
        root.mkdir(parents=True, exist_ok=True)
        os.rmdir(tempfile.mkdtemp(dir=root, prefix=".probe.", suffix=".tmp"))
        return root
    except OSError as exc:
        return _fallback(root, exc.strerror or str(exc))


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(OSError):
            path.unlink()


def _discard(entry: Path) -> bool:
    """Move a damaged entry out of the way (atomically) and delete it; False if the cache does not permit it."""
    aside = entry.with_name(f".{entry.name}.{os.getpid()}.{threading.get_ident()}.damaged.tmp")
    try:
        os.rename(entry, aside)
    except FileNotFoundError:
        return True  # another process removed it already
    except OSError:
        return False
    _remove(aside)
    return True


def _publish(root: Path, key: str, filename: str, make: Callable[[Path], None]) -> Path:
    """Build into a staging folder in ``root`` and rename it to ``root/key``; the first builder to rename wins."""
    staging = Path(tempfile.mkdtemp(dir=root, prefix=f".{key}.", suffix=".tmp"))
    try:
        make(staging / filename)
        (staging / f"{filename}.sha256").write_text(f"{sha256_file(staging / filename)}  {filename}\n")
        staging.chmod(0o755)  # mkdtemp's 0700 would hide the entry from other users of a shared cache
        try:
            os.rename(staging, root / key)
        except OSError as exc:
            if exc.errno not in (errno.EEXIST, errno.ENOTEMPTY):
                raise
    finally:
        _remove(staging)  # gone after a successful rename; removed after a lost race or an interruption
    return root / key


def cached_file(key: str, filename: str, make: Callable[[Path], None], what: str, force: bool = False) -> Path:
    """The verified file ``filename`` of cache entry ``key``, built with ``make(path)`` when missing or damaged.

    ``what`` names the artefact in messages ("FMI 2 FMU"). ``force`` rebuilds a sound entry too.
    """
    root = cache_dir()
    entry = root / key
    if entry.exists() or entry.is_symlink():
        problem = _problem(entry, filename)
        if problem is None and not force:
            return entry / filename
        if problem:
            _say(f"the cached {what} in {entry} is damaged ({problem}); rebuilding it")
        if not _discard(entry):
            root = _fallback(root, f"cannot remove {entry}")
    else:
        root = _writable_root(root)
    if root != cache_dir() and (root / key).exists() and _problem(root / key, filename) is None and not force:
        return root / key / filename  # built into the temporary cache earlier in this process
    with interruptible():
        entry = _publish(root, key, filename, make)
    problem = _problem(entry, filename)
    if problem:
        raise BuildError(f"the rebuilt {what} in {entry} is still damaged ({problem}); delete {entry} and retry")
    return entry / filename


class _Terminated(BaseException):
    """SIGTERM arrived during a build: unwinds through every ``finally`` (cleanup), then the process dies of it."""


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Run a build so that SIGTERM unwinds it like Ctrl-C does (removing temporary files on the way out).

    Only where SIGTERM still has its default action (an application that installed its own handler keeps it) and
    only in the main thread (the only one that may set handlers). After the cleanup the process is terminated by
    the same signal, so its exit status is unchanged (143 from a shell).
    """
    install = (threading.current_thread() is threading.main_thread()
               and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL)
    if not install:
        yield
        return

    def on_term(signum, frame):  # noqa: ANN001 - signal handler signature
        raise _Terminated()

    signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    except _Terminated:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        raise  # not reached: the default action ends the process
    finally:
        if signal.getsignal(signal.SIGTERM) is on_term:
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
