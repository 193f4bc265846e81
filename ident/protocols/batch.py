"""Batches of independent runs (friction levels, drives, Monte Carlo samples) on Dask.

By default a local ``dask.distributed`` cluster of worker processes (one thread each: every task drives its own
FMU instance); with ``scheduler="tcp://HOST:PORT"`` the batch goes to an existing cluster. Each worker builds or
loads the FMU itself (``fmu_build`` caches it per machine, atomically), so only parameters and results travel.
Results come back in the order of the inputs, whatever order the workers finish in.
"""
from __future__ import annotations

import logging
import os
import threading
from typing import Any, Callable, Sequence, TypeVar

from tqdm import tqdm

T = TypeVar("T")
R = TypeVar("R")


def default_workers() -> int:
    return max(1, min(os.cpu_count() or 1, 8))


def run_batch(fn: Callable[[T], R], items: Sequence[T], *, scheduler: str | None = None, workers: int | None = None,
              progress: bool = False, desc: str = "runs") -> list[R]:
    """``[fn(x) for x in items]`` on Dask; ``workers=0`` runs serially in this process (no Dask at all)."""
    items = list(items)
    if not items:
        return []
    if workers == 0 and scheduler is None:
        return [fn(x) for x in tqdm(items, desc=desc, disable=not progress)]
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        n = min(workers or default_workers(), len(items))
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster if cluster is not None else scheduler)
    try:
        futures = client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[Any] = [None] * len(items)
        with tqdm(total=len(items), desc=desc, disable=not progress) as bar:
            for future in as_completed(futures):
                results[index[future.key]] = future.result()  # re-raises a worker's exception here
                bar.update()
        return results
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


class WorkerPool:
    """One set of workers for several batches (a diagnosis runs a few per step, and starting a local cluster costs
    seconds): a local ``dask.distributed`` cluster of ``workers`` processes (one thread each), an existing cluster
    (``scheduler``), or none (``workers=0``: every batch runs serially in this process). Results come back in the
    order of the inputs. The workers start in the background (the caller's first work, e.g. a base fit, overlaps
    their start-up); the first batch waits for them. Ctrl-C while a batch runs cancels its tasks and stops the local
    workers at once (their processes are killed, not asked to finish the simulation they are in), then re-raises
    ``KeyboardInterrupt``."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None):
        self.workers = default_workers() if workers is None and scheduler is None else workers
        self.scheduler = scheduler
        self.cluster: Any = None
        self.client: Any = None
        self._starting: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def serial(self) -> bool:
        return self.workers == 0 and self.scheduler is None

    def __enter__(self) -> "WorkerPool":
        if not self.serial:
            self._starting = threading.Thread(target=self._start, name="hdrive-workers", daemon=True)
            self._starting.start()
        return self

    def _start(self) -> None:
        try:
            from dask.distributed import Client, LocalCluster

            if self.scheduler is None:
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=None)
            self.client = Client(self.cluster if self.cluster is not None else self.scheduler)
        except BaseException as exc:  # noqa: BLE001 - re-raised in the caller's thread by _ready
            self._error = exc

    def _ready(self) -> None:
        """Wait for the workers (in short slices, so that Ctrl-C is seen at once)."""
        while self._starting is not None and self._starting.is_alive():
            self._starting.join(0.1)
        if self._error is not None:
            raise RuntimeError(f"the Dask workers did not start: {self._error}") from self._error

    def __exit__(self, kind: Any, exc: Any, tb: Any) -> None:
        self.close(kill=kind is not None and issubclass(kind, KeyboardInterrupt))

    def share(self, value: Any) -> Any:
        """``value`` sent to the workers once (a log of megabytes used by every task); pass the result to ``map``
        in place of the value."""
        if self.serial:
            return value
        self._ready()
        return self.client.scatter(value, broadcast=True)

    def map(self, fn: Callable[[T], R], items: Sequence[T], *, progress: bool = False, desc: str = "runs") -> list[R]:
        """``[fn(x) for x in items]`` on the pool's workers."""
        items = list(items)
        if not items:
            return []
        if self.serial:
            return [fn(x) for x in tqdm(items, desc=desc, disable=not progress)]
        from dask.distributed import as_completed

        self._ready()
        futures = self.client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        results: list[Any] = [None] * len(items)
        try:
            with tqdm(total=len(items), desc=desc, disable=not progress) as bar:
                for future in as_completed(futures):
                    results[index[future.key]] = future.result()  # re-raises a worker's exception here
                    bar.update()
        except BaseException:
            self.client.cancel(futures)
            raise
        return results

    def close(self, kill: bool = False) -> None:
        """Stop the pool; ``kill``: kill the local worker processes first (Ctrl-C: do not wait for a simulation)."""
        if self._starting is not None and self._starting.is_alive():
            if kill:  # Ctrl-C while the workers start: their processes are daemons, gone when this one exits
                return
            self._starting.join()  # a cluster half-started cannot be closed; Dask starts it within seconds
        if self.cluster is not None and kill:
            logging.getLogger("distributed").setLevel(logging.CRITICAL)
            for nanny in list(getattr(self.cluster, "workers", {}).values()):
                nanny.auto_restart = False
                proc = getattr(getattr(getattr(nanny, "process", None), "process", None), "_process", None)
                if proc is not None and proc.is_alive():
                    proc.kill()
        try:
            if self.client is not None:
                self.client.close(timeout=2)
            if self.cluster is not None:
                self.cluster.close(timeout=2)
        except Exception:  # noqa: BLE001 - closing after a kill may time out; the processes are gone
            pass
        self.client = self.cluster = None
