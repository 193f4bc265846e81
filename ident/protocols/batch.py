"""Batches of independent runs (friction levels, drives, Monte Carlo samples) on Dask.

By default a local ``dask.distributed`` cluster of worker processes (one thread each: every task drives its own
FMU instance); with ``scheduler="tcp://HOST:PORT"`` the batch goes to an existing cluster. Each worker builds or
loads the FMU itself (``fmu_build`` caches it per machine, atomically), so only parameters and results travel.
Results come back in the order of the inputs, whatever order the workers finish in.
"""
from __future__ import annotations

import os
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
