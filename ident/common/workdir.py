"""The process's working directory, which fmpy changes while it loads an FMU's library.

fmpy loads a library with the working directory switched to the library's folder: here a folder of one plant's
unpacked copy of the FMU, deleted when that plant closes. The working directory belongs to the whole process, so
two things must not overlap that switch:
- another thread's load (it would take the first one's folder for the directory to return to, and leave the process
  there);
- the start of worker processes, which inherit the working directory. Measured: a diagnosis fits its base model
  while its Dask workers start in a background thread; a worker started inside a load kept the plant's folder as
  its working directory, the plant closed, and every FMU that worker loaded afterwards failed with "[Errno 2] No
  such file or directory" (2 of the 781 diagnoses recorded on the benchmark machine: four or five candidates of a
  step "not fitted").

Both hold ``kept_working_directory``.
"""
from __future__ import annotations

import contextlib
import os
import threading
from typing import Iterator

_LOCK = threading.RLock()


@contextlib.contextmanager
def kept_working_directory() -> Iterator[None]:
    """Hold the process's working directory: no other holder runs meanwhile, and the directory is restored when
    the block ends, even when the block left it elsewhere (fmpy does not change it back when a load fails)."""
    with _LOCK:
        try:
            before = os.getcwd()
        except FileNotFoundError:  # already a deleted folder: nothing sound to return to
            before = None
        try:
            yield
        finally:
            if before is not None:
                with contextlib.suppress(OSError):
                    if os.getcwd() != before:
                        os.chdir(before)
