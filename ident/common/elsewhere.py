"""Work run on another core while the caller goes on: the contract between a fit that can use it (the
identifier's second start path, ``ident.fitting.identify.fit_tracks``) and what provides it (the diagnosis's
workers, ``ident.protocols.batch.WorkerPool.beside``), so that neither imports the other.

Why a cancel: the fit starts the work before it knows whether it will need it (that is the point: the two run at
once), and where it turns out not to, the core must be free again for the next work at once, not after minutes."""
from __future__ import annotations

from typing import Any, Callable, Protocol

#: ``fn(args, cancelled)``: ``cancelled()`` turns true once the caller no longer needs the result
Task = Callable[[tuple, Callable[[], bool]], Any]


class NotRunElsewhere(RuntimeError):
    """The work could not run elsewhere (e.g. the workers did not start): the caller makes its result itself."""


class Running(Protocol):
    """Work started elsewhere: ``result()`` waits for it (re-raising the work's own exception, or
    ``NotRunElsewhere``); ``cancel()`` says it is no longer needed."""

    def result(self) -> Any: ...

    def cancel(self) -> None: ...


class Elsewhere(Protocol):
    """Starts ``fn(args, cancelled)`` on another core and returns at once."""

    def __call__(self, fn: Task, args: tuple) -> Running: ...
