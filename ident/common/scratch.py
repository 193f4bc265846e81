"""Temporary folders a process owns: named with its process id and its host, so that a later process can remove
those of a process that is gone (``remove_orphaned``).

Why: a process removes its folders when it ends, but one killed before ``atexit`` runs keeps them: a script calling
``ident.diagnose`` stopped by SIGTERM (Python's default handler skips ``atexit``; the command line has its own and
leaves nothing), or a Dask worker killed outright. Measured: 21 unpacked FMUs of about 220 KB each in /tmp after a day
of interrupted runs (stop 73); a diagnosis's workers' folder of 1.4 MB (their own unpacked FMUs inside) left by a
script stopped with SIGTERM (stop 75). Each kind of folder has its own prefix; whoever makes a new one first removes
the orphaned ones of its kind.
"""
from __future__ import annotations

import hashlib
import os
import shutil
import socket
import tempfile
from pathlib import Path


def host_tag() -> str:
    """8 hex digits of this host's name: process ids are only compared on the host (and container) that made them."""
    return hashlib.blake2b(socket.gethostname().encode(), digest_size=4).hexdigest()


def owned_dir(prefix: str) -> str:
    """A new temporary folder named ``prefix``, this process's id, the host's tag (``host_tag``), then mkdtemp's
    random suffix."""
    return tempfile.mkdtemp(prefix=f"{prefix}{os.getpid()}-{host_tag()}-")


def remove_orphaned(prefix: str, root: str | Path | None = None) -> list[Path]:
    """Remove the folders ``owned_dir(prefix)`` made (under ``root``, default the temporary folder) whose process is
    gone, made on this host; return them. A folder whose process id is alive is kept, whoever owns it (a reused id
    only delays the removal); a folder of another host (a shared /tmp) is never touched."""
    if os.name != "posix":   # os.kill(pid, 0) asks only on POSIX
        return []
    removed = []
    for folder in Path(root if root is not None else tempfile.gettempdir()).glob(f"{prefix}*-{host_tag()}-*"):
        pid = folder.name[len(prefix):].split("-", 1)[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
    return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)   # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:   # another user's live process
        return True
    return True
