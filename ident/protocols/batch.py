"""Batches of independent runs (friction levels, drives, Monte Carlo samples) on Dask.

By default a local ``dask.distributed`` cluster of worker processes (one thread each: every task drives its own
FMU instance); with ``scheduler="tcp://HOST:PORT"`` the batch goes to an existing cluster. Tasks that spend their
time in compiled code releasing the GIL (the protocols' compiled loops, ``threads=True``) run locally on Dask's
threaded scheduler in this process instead: as parallel as worker processes, without their start-up (1-2 s, more
than a whole compiled friction sweep) and without shipping parameters and results between processes. Each worker builds or
loads the FMU itself (``fmu_build`` caches it per machine, atomically), so only parameters and results travel.
Results come back in the order of the inputs, whatever order the workers finish in.

Faults are named, never waited out: a scheduler that cannot be reached within ``CONNECT_TIMEOUT_S`` and a cluster
that has lost every worker while tasks are pending raise ``BatchError``. Those clocks only decide *whether the
cluster is alive*; no result depends on them. Local workers keep their temporary files (unpacked FMUs, Dask's
scratch space) in one folder that is removed with the cluster, also when the batch is interrupted.
"""
from __future__ import annotations

import atexit
import logging
import multiprocessing
import os
import shutil
import sys
import threading
import uuid
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence, TypeVar

from tqdm import tqdm

from ..common.elsewhere import Elsewhere, NotRunElsewhere, Task
from ..common.scratch import owned_dir, remove_orphaned
from ..common.workdir import kept_working_directory

T = TypeVar("T")
R = TypeVar("R")

CONNECT_TIMEOUT_S = 10.0   # how long a scheduler may take to answer before it counts as unreachable
LIVENESS_POLL_S = 5.0      # how often a batch waiting for results checks that the cluster still has workers


_SCRATCH: set[str] = set()   # local workers' temporary folders: removed after the batch and once more at exit
#: local workers' folder (their scratch space, TMPDIR and unpacked FMUs): this prefix, then ``owned_dir``'s naming
_WORKERS_PREFIX = "hdrive-workers-"


@atexit.register   # registered before Dask is imported, so it runs after Dask's own exit handlers
def _remove_scratch() -> None:
    for folder in list(_SCRATCH):
        shutil.rmtree(folder, ignore_errors=True)


def _new_scratch() -> str:
    """A new folder for local workers, the orphaned ones of processes killed before they removed theirs removed
    first (``ident.common.scratch``). An interrupted cluster may still write into it while it shuts down: it is
    removed after the batch and once more at exit (``_SCRATCH``)."""
    remove_orphaned(_WORKERS_PREFIX)
    scratch = owned_dir(_WORKERS_PREFIX)
    _SCRATCH.add(scratch)
    return scratch


def abandon_local_workers() -> None:
    """For a process about to leave without the interpreter's teardown (``os._exit`` after Ctrl-C / SIGTERM): kill
    the local worker processes and remove their scratch folders. Without it the exit waits for workers caught in
    their start-up (measured 11 s) -- the teardown has nothing else to do for an interrupted batch."""
    import multiprocessing

    for child in multiprocessing.active_children():
        child.kill()
    _remove_scratch()


class BatchError(RuntimeError):
    """The batch cannot run: bad worker count, an unreachable scheduler, or a cluster without workers."""


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def check_workers(workers: int | None) -> None:
    """``workers`` is None (the machine's cores), 0 (serial, no Dask) or a positive count."""
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 0):
        raise BatchError(f"workers = {workers!r}: use a whole number >= 0 (0 = serial, no Dask)")


def connect(scheduler: str) -> Any:
    """A client of the cluster at ``scheduler``, or ``BatchError`` naming it when it does not answer in time."""
    from dask.distributed import Client

    try:
        return Client(scheduler, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError, ValueError) as exc:
        raise BatchError(f"cannot reach the Dask scheduler at {scheduler} within {CONNECT_TIMEOUT_S:g} s: "
                         f"{exc}") from None


def run_batch(fn: Callable[[T], R], items: Sequence[T], *, scheduler: str | None = None, workers: int | None = None,
              progress: bool = False, desc: str = "runs", threads: bool = False) -> list[R]:
    """``[fn(x) for x in items]`` on Dask; ``workers=0`` runs serially in this process (no Dask at all).

    ``threads``: ``fn`` spends its time in compiled code that releases the GIL, so a local batch runs on ``workers``
    threads of this process (Dask's threaded scheduler); a one-item batch runs serially. A cluster at
    ``scheduler`` is used as given."""
    check_workers(workers)
    items = list(items)
    if not items:
        return []
    if (workers == 0 or (threads and len(items) == 1)) and scheduler is None:
        return [fn(x) for x in tqdm(items, desc=desc, disable=not progress)]
    if threads and scheduler is None:
        return _run_threads(fn, items, min(workers or default_workers(), len(items)), progress, desc)
    if scheduler is not None:
        client = connect(scheduler)
        try:
            return _gather(client, fn, items, progress, desc, scheduler)
        finally:
            client.close()
    with _local_client(min(workers or default_workers(), len(items))) as client:
        return _gather(client, fn, items, progress, desc, "the local cluster")


Runner = Callable[..., list]


@contextmanager
def batch_session(*, scheduler: str | None = None, workers: int | None = None,
                  threads: bool = False) -> Iterator[Runner]:
    """One cluster for several batches: yields ``run(fn, items, progress=False, desc="runs")``, which works like
    ``run_batch`` but reuses the session's workers (a study of several stages starts its cluster once). Same
    options and faults as ``run_batch``; the cluster is shut down when the block ends, also on an interrupt. With
    ``threads`` (compiled tasks that release the GIL) and no ``scheduler``, every batch runs on threads of this
    process, as ``run_batch(..., threads=True)`` does: there is no cluster to keep."""
    check_workers(workers)
    if scheduler is None and (workers == 0 or threads):
        yield lambda fn, items, progress=False, desc="runs": run_batch(fn, items, workers=workers, progress=progress,
                                                                        desc=desc, threads=threads)
        return
    with (_remote_client(scheduler) if scheduler is not None else _local_client(workers or default_workers())) \
            as client:
        where = scheduler or "the local cluster"
        yield lambda fn, items, progress=False, desc="runs": (
            _gather(client, fn, list(items), progress, desc, where) if len(items) else [])


@contextmanager
def _remote_client(scheduler: str) -> Iterator[Any]:
    client = connect(scheduler)
    try:
        yield client
    finally:
        client.close()


def _run_threads(fn: Callable[[T], R], items: list[T], n: int, progress: bool, desc: str) -> list[R]:
    """``n`` lanes on Dask's threaded scheduler, each taking the next item in input order until none is left (the
    order of the items is the order of the work: callers put the longest first). When the batch ends with an
    exception (a task's, Ctrl-C, SIGTERM), ``stop`` is set: the lanes take no new item and the compiled loops
    still running stop at their next chunk (``ident.protocols.compiled.stopped_by``)."""
    import itertools
    import threading

    import dask

    from .compiled import stopped_by

    results: list[Any] = [None] * len(items)
    stop = threading.Event()
    order = itertools.count()   # next() is atomic under the GIL: every index is taken once
    bar = tqdm(total=len(items), desc=desc, disable=not progress)

    def lane() -> None:
        with stopped_by(stop):
            while not stop.is_set():
                i = next(order)
                if i >= len(items):
                    return
                results[i] = fn(items[i])
                bar.update()

    try:
        dask.compute(*[dask.delayed(lane, pure=False)() for _ in range(n)], scheduler="threads", num_workers=n)
    except BaseException:
        stop.set()
        raise
    finally:
        bar.close()
    return results


#: what a local worker logs (with a traceback) when its heartbeat finds the scheduler gone. A local cluster's
#: scheduler lives in this process, so that is this process closing the cluster: Dask's race between a worker's
#: heartbeat and the scheduler's close (dask/distributed#7105), not news for the user. Measured: a traceback on
#: stderr after a diagnosis that ended normally, 1 of about 40 runs.
_CLOSING_HEARTBEAT = "Failed to communicate with scheduler during heartbeat"


class _ClosingHeartbeat(logging.Filter):
    """Drops ``_CLOSING_HEARTBEAT`` records, lets every other one through."""

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(_CLOSING_HEARTBEAT)


def _quiet_closing_heartbeats() -> None:
    """In a local worker process: drop its ``_CLOSING_HEARTBEAT`` records (``_client_of`` runs it on each)."""
    log = logging.getLogger("distributed.worker")
    if not any(isinstance(f, _ClosingHeartbeat) for f in log.filters):
        log.addFilter(_ClosingHeartbeat())


def _client_of(cluster: Any) -> Any:
    """A client of the local ``cluster``, its workers' closing heartbeats quiet (``_quiet_closing_heartbeats``)."""
    from dask.distributed import Client

    client = Client(cluster)
    client.run(_quiet_closing_heartbeats)
    return client


def _new_cluster(n: int, scratch: str) -> Any:
    """A local Dask cluster of ``n`` single-threaded worker processes whose scratch space (and ``TMPDIR``) is
    ``scratch``. Started holding the working directory: the workers inherit it, and no FMU load may switch it
    meanwhile (``ident.common.workdir``). The workers' own warnings (e.g. tasks cancelled by an interrupt) are not
    the user's business. Its dashboard takes a free port: Dask's default (8787) is taken by the first of two runs at
    once, and the second warned about it on stderr."""
    from dask.distributed import LocalCluster

    with kept_working_directory():
        return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                            local_directory=scratch, env={"TMPDIR": scratch}, silence_logs=logging.ERROR)


@contextmanager
def _local_client(n: int) -> Iterator[Any]:
    """A client of a new local cluster of ``n`` worker processes, shut down (and its scratch folder removed) when
    the block ends."""
    import dask

    _refuse_while_importing_main()
    scratch = _new_scratch()
    cluster = client = None
    try:
        with dask.config.set({"temporary-directory": scratch}):
            with _signals_deferred():  # an interrupt during start-up is handled once the cluster can be shut down
                cluster = _new_cluster(n, scratch)
                client = _client_of(cluster)
            yield client
    finally:
        _shut_down(client, cluster, interrupted=sys.exc_info()[0] is not None)
        shutil.rmtree(scratch, ignore_errors=True)


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """Hold SIGINT / SIGTERM back while the block runs (they are delivered when it ends); main thread only."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held = {signal.SIGINT, signal.SIGTERM}
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _shut_down(client: Any, cluster: Any, interrupted: bool) -> None:
    """Shut the client and the local cluster down. When the batch was interrupted (Ctrl-C, SIGTERM, an error), the
    worker processes are killed first, so that the shutdown takes a moment rather than waiting for running tasks;
    Dask's own complaints about that are the expected end of an interrupted batch, not news for the user."""
    if interrupted:
        for child in multiprocessing.active_children():
            child.kill()
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.CRITICAL)
    try:
        for part in (client, cluster):
            if part is not None:
                try:
                    part.close(timeout=0.5 if interrupted else 5)
                except Exception:  # noqa: BLE001 - see the docstring
                    pass
    finally:
        if not interrupted:  # after an interrupt the process is on its way out: Dask's late complaints stay quiet
            quiet.setLevel(level)


def _gather(client: Any, fn: Callable[[T], R], items: list[T], progress: bool, desc: str, where: str,
            order: Sequence[int] | None = None) -> list[R]:
    """Submit (in ``order``, indices into ``items``: the first submitted first; default as given), then collect in
    input order; a worker's exception is re-raised here; ``BatchError`` when the cluster has no worker left while
    tasks are pending (it would wait forever). The workers are counted by asking the scheduler (``nthreads``), not
    read from ``scheduler_info()``: that returns the client's cached identity, which the client's own periodic
    refresh overwrites with a worker-less summary (measured: 1 call in 10,000 came back without workers on an idle
    machine, a third of them with a 1 ms refresh; a two-effect diagnosis under load stopped with "no workers left"
    while both were at work). The progress bar is redrawn at every liveness poll, so that its elapsed time shows a
    batch still at work through a task of several minutes."""
    from dask.distributed import wait

    order = range(len(items)) if order is None else order
    futures = client.map(fn, [items[i] for i in order], pure=False)
    index = {f.key: i for i, f in zip(order, futures)}
    results: list[Any] = [None] * len(items)
    pending = set(futures)
    with tqdm(total=len(items), desc=desc, disable=not progress) as bar:
        while pending:
            try:
                done, pending = wait(pending, timeout=LIVENESS_POLL_S, return_when="FIRST_COMPLETED")
            except TimeoutError:
                if not client.nthreads():
                    client.cancel(list(pending))
                    raise BatchError(f"{where} has no workers left; {len(pending)} of {len(items)} {desc} "
                                     "unfinished") from None
                bar.refresh()   # the elapsed time moves on while a long task runs: the user sees the work alive
                continue
            for future in done:
                results[index[future.key]] = future.result()  # re-raises a worker's exception here
                bar.update()
    return results


class Beside:
    """One task on a local worker (``WorkerPool.beside``), submitted and collected by a thread of its own. Its
    cancel is a file in the pool's scratch folder, which the task's ``cancelled()`` looks for (a look costs about a
    microsecond: a fit can ask before every simulation). A failure of the pool rather than of the task (the workers
    did not start, or died) comes back from ``result`` as ``NotRunElsewhere``: the caller then runs it itself."""

    def __init__(self, pool: WorkerPool, fn: Task, args: tuple):
        self._flag = os.path.join(str(pool._scratch), f"cancelled-{uuid.uuid4().hex}")
        self._out: list[tuple[bool, Any]] = []   # (the task raised, its result or exception)
        self._failed: BaseException | None = None
        self._thread = threading.Thread(target=self._run, args=(pool, fn, args), name="hdrive-beside", daemon=True)
        self._thread.start()

    def _run(self, pool: WorkerPool, fn: Task, args: tuple) -> None:
        try:
            pool._ready()
            if not os.path.exists(self._flag):
                self._out.append(_gather(pool.client, _until_cancelled, [(fn, args, self._flag)], False, "beside",
                                         "the local cluster")[0])
        except BaseException as exc:  # noqa: BLE001 - the pool's failure, handed to ``result``
            self._failed = exc

    def result(self) -> Any:
        _join(self._thread)
        if self._failed is not None or not self._out:
            raise NotRunElsewhere(f"the task could not run on a worker: {self._failed or 'cancelled'}")
        raised, value = self._out[0]
        if raised:
            raise value
        return value

    def cancel(self) -> None:
        try:
            Path(self._flag).touch()
        except OSError:   # the pool and its folder are gone already, and the task with them
            pass


def _join(thread: threading.Thread) -> None:
    """Wait for ``thread`` in short slices, so that Ctrl-C is seen at once (a plain join blocks signals' handling
    in the main thread until the thread ends)."""
    while thread.is_alive():
        thread.join(0.1)


def _until_cancelled(item: tuple[Task, tuple, str]) -> tuple[bool, Any]:
    """A ``Beside`` task on the worker: (whether it raised, its result or exception); the task's own exception comes
    back as a value, so that ``Beside`` tells it from the pool's failures."""
    fn, args, flag = item
    try:
        return False, fn(args, lambda: os.path.exists(flag))
    except Exception as exc:  # noqa: BLE001 - re-raised by Beside.result in the caller
        return True, exc


def _start_hint() -> str:
    """What to do when the workers failed because the caller's main script runs hdrive's work at import: each worker
    is a new process that imports the main module (multiprocessing's spawn), so the script started workers again
    from inside a worker (measured: Dask only says "Nanny failed to start"). Inside such a worker the pool is refused
    before it starts, with this advice (``_refuse_while_importing_main``); in the script's own process, whose
    workers died of it, only the script's source tells (it has no ``__main__`` guard)."""
    main = sys.modules.get("__main__")
    script = getattr(main, "__file__", None)   # a module run with -m (a __spec__) is not imported again by spawn
    try:
        unguarded = getattr(main, "__spec__", None) is None and str(script).endswith(".py") \
            and "__main__" not in Path(str(script)).read_text()
    except (OSError, UnicodeDecodeError):
        unguarded = False
    return _UNGUARDED.format(script=script) if unguarded else ""


_UNGUARDED = (". The workers are new processes that import {script}, and it starts hdrive's work when imported: put "
              "that work under `if __name__ == \"__main__\":`, or pass workers=0 to run in this process")


def _refuse_while_importing_main() -> None:
    """``BatchError`` at once where this process is a worker still importing the caller's main script (a script that
    runs hdrive's work at import, without a ``__main__`` guard: multiprocessing's spawn imports it in every worker).
    Workers started there would fail anyway (the standard library refuses to start a process during that import),
    but the work before the first batch would run in full in every worker first. Measured: an unguarded script's
    diagnosis of a clean log (which needs no batch) ran three times, once in the script and once in each of its two
    workers, and printed its answer three times; one with a hidden effect failed after every worker had fitted the
    base model. The flag read is the one the standard library's own refusal reads (absent elsewhere: no check)."""
    if getattr(multiprocessing.current_process(), "_inheriting", False):
        raise BatchError("the local Dask workers did not start: this process is a worker importing the main script"
                         + _UNGUARDED.format(script="your main script"))


class WorkerPool:
    """One set of workers for several batches (a diagnosis runs a few per step, and starting a local cluster costs
    seconds): a local cluster of ``workers`` processes (one thread each, their scratch space in one folder removed
    with them), an existing cluster (``scheduler``), or none (``workers=0``: every batch runs serially in this
    process). Results come back in the order of the inputs. The local workers start in the background (the caller's
    first work, e.g. a base fit, overlaps their start-up); the first batch waits for them. Ctrl-C cancels the
    running tasks and kills the local workers (``_shut_down``), then re-raises ``KeyboardInterrupt``."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        check_workers(workers)
        self.workers = default_workers() if workers is None and scheduler is None else workers
        self.scheduler = scheduler
        self.cluster: Any = None
        self.client: Any = None
        self._scratch: str | None = None
        self._starting: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def serial(self) -> bool:
        return self.workers == 0 and self.scheduler is None

    def __enter__(self) -> WorkerPool:
        if self.scheduler is not None:
            self.client = connect(self.scheduler)
        elif not self.serial:
            _refuse_while_importing_main()
            self._scratch = _new_scratch()
            self._starting = threading.Thread(target=self._start, name="hdrive-workers", daemon=True)
            self._starting.start()
        return self

    def _start(self) -> None:
        try:
            import dask

            with dask.config.set({"temporary-directory": self._scratch}):
                self.cluster = _new_cluster(self.workers, self._scratch)
                self.client = _client_of(self.cluster)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread by _ready
            self._error = exc

    def _ready(self) -> None:
        """Wait for the local workers (``_join``)."""
        if self._starting is not None:
            _join(self._starting)
        if self._error is not None:
            why = str(self._error).rstrip(".")
            raise BatchError(f"the local Dask workers did not start: {why}{_start_hint()}") from self._error

    def __exit__(self, kind: object, exc: object, tb: object) -> None:
        self.close(interrupted=kind is not None)

    def share(self, value: Any) -> Any:
        """``value`` sent to the workers once (a log of megabytes used by every task); pass the result to ``map``
        in place of the value."""
        if self.serial:
            return value
        self._ready()
        return self.client.scatter(value, broadcast=True)

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, progress: bool = False, desc: str = "runs",
            cost: Sequence[float] | None = None) -> list[R]:
        """``[fn(x) for x in items]`` on the pool's workers. ``cost``: each item's expected cost (any unit): the
        costliest are submitted first, so that a batch of uneven tasks does not end waiting on a costly one started
        last (longest first; measured with 7 tasks of a diagnosis step's spread on 2 workers: 5.9 s instead of 6.7 s,
        the longest 5.6 s). The results are the same, in the same order."""
        items = list(items)
        if cost is not None and len(cost) != len(items):
            raise ValueError(f"cost has {len(cost)} entries for {len(items)} items")
        if not items:
            return []
        if self.serial:
            return [fn(x) for x in tqdm(items, desc=desc, disable=not progress)]
        self._ready()
        order = None if cost is None else sorted(range(len(items)), key=lambda i: -cost[i])
        return _gather(self.client, fn, items, progress, desc, self.scheduler or "the local cluster", order)

    @property
    def elsewhere(self) -> Elsewhere | None:
        """``beside`` where the pool has local workers; None where it runs serially or on a cluster elsewhere (whose
        workers share no folder with this process to see a cancel in)."""
        return self.beside if self._scratch is not None else None

    def beside(self, fn: Task, args: tuple) -> Beside:
        """``fn(args, cancelled)`` on one local worker while this process goes on (``ident.common.elsewhere``);
        it is submitted from a thread as soon as the workers are up, so this returns at once even while they
        start. Only a pool with local workers has such a core (``elsewhere``)."""
        if self._scratch is None:
            raise BatchError("work beside this process needs local workers: this pool "
                             + ("runs serially" if self.serial else f"runs on {self.scheduler}"))
        return Beside(self, fn, args)

    def close(self, interrupted: bool = False) -> None:
        """Stop the pool; ``interrupted``: kill the local workers rather than wait for their tasks."""
        if self._starting is not None and self._starting.is_alive():
            if interrupted:  # interrupted while they start: their processes are daemons, gone when this one exits
                return
            self._starting.join()
        if self.scheduler is not None:
            if self.client is not None:
                self.client.close()
        else:
            _shut_down(self.client, self.cluster, interrupted)
        if self._scratch is not None:
            shutil.rmtree(self._scratch, ignore_errors=True)
        self.client = self.cluster = None
