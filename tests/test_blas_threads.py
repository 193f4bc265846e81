"""hdrive computes with one BLAS thread unless the user chose a count (``ident.common.blas``): the fits' small
matrices gain nothing from OpenBLAS's threads, which busy-wait and took half the CPU of a serial diagnosis."""
from __future__ import annotations

import os
import subprocess
import sys
import threading

from threadpoolctl import threadpool_info

from ident.common.blas import one_blas_thread


def _blas_threads() -> list[int]:
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_thread_inside_nested_blocks_and_the_count_restored_after() -> None:
    """The main thread sets the limit and lifts it when its outermost block ends; a block in another thread
    (a Dask thread running a fit) neither sets nor lifts it."""
    import numpy  # noqa: F401  (loads NumPy's BLAS)

    before = _blas_threads()
    assert before, "no BLAS library loaded"
    seen: dict[str, list[int]] = {}

    def other(key: str) -> None:
        with one_blas_thread():
            seen[key] = _blas_threads()

    with one_blas_thread():
        with one_blas_thread():
            seen["nested"] = _blas_threads()
        seen["outer"] = _blas_threads()
        t = threading.Thread(target=other, args=("thread inside",))
        t.start()
        t.join(10)
    seen["after"] = _blas_threads()
    t = threading.Thread(target=other, args=("thread alone",))
    t.start()
    t.join(10)
    assert all(n == 1 for key in ("nested", "outer", "thread inside") for n in seen[key]), seen
    assert seen["after"] == before and seen["thread alone"] == before, (before, seen)


def test_a_count_the_user_set_is_kept() -> None:
    code = ("import numpy; from threadpoolctl import threadpool_info as i; from ident.common.blas import "
            "one_blas_thread as o\nb = [x['num_threads'] for x in i()]\nwith o(): a = [x['num_threads'] for x in i()]"
            "\nprint(b == a, b)")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.startswith("True"), out.stdout + out.stderr
