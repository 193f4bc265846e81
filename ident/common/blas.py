"""One BLAS thread while hdrive computes, unless the user chose otherwise.

The fits' linear algebra is many small products and factorisations of tall, narrow matrices (residuals x a dozen
parameters). OpenBLAS's worker threads buy no wall time there and busy-wait between calls: measured on 2 cores, a
serial diagnosis of a 3 s log took 8.8 s wall and 16.6 s of CPU with NumPy's default two BLAS threads, 8.7 s and
8.6 s with one; a 10 s identification 2.8 s wall either way, 4.5 s against 2.8 s of CPU; the default test run 307 s
against 221 s. The CPU they burn is taken from this process's own workers and from anything else on the machine, so
on a loaded machine one thread is also the faster. The parallelism hdrive uses is across worker processes (Dask
starts those with one BLAS thread already), and threads of this process in the compiled protocol loops.

A user who set ``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS`` or ``MKL_NUM_THREADS`` before hdrive was imported keeps
their setting. (Read once, at import: Dask's local cluster writes all three into this process's environment when it
starts its workers, and that is not the user's choice.)"""
from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from contextlib import contextmanager

_USER_CHOICE = any(name in os.environ for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"))
_DEPTH = 0
_LIMITS = None


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Limit the loaded BLAS libraries to one thread inside the block, lifted when the outermost block ends.

    Only the main thread sets and lifts the limit: OpenBLAS's count is the process's, and a count restored from
    another thread does not take (measured with threadpoolctl 3.8 and OpenBLAS 0.3.31), so a block in another
    thread runs under whatever the main thread set (the command line sets it for the whole command). Does nothing
    where the user set a thread count."""
    global _DEPTH, _LIMITS
    if _USER_CHOICE or threading.current_thread() is not threading.main_thread():
        yield
        return
    from threadpoolctl import threadpool_limits

    if _DEPTH == 0:
        _LIMITS = threadpool_limits(limits=1, user_api="blas")
    _DEPTH += 1
    try:
        yield
    finally:
        _DEPTH -= 1
        if _DEPTH == 0 and _LIMITS is not None:
            _LIMITS.restore_original_limits()
            _LIMITS = None
