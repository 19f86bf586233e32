"""One BLAS thread while pcdet works: ``with one_blas_thread(): ...``, or ``@on_one_blas_thread`` on a function.

numpy and scipy each ship an OpenBLAS that starts one thread per core for every matrix product and
decomposition. pcdet's products are small (a few poses by a few thousand correspondences, batches of 3 x 3
decompositions) and it already runs its per-model and per-hypothesis work on its own threads, beside open3d's
OpenMP threads; there OpenBLAS's threads only wait on each other and take cores from the work. Measured on an
8-object real frame (``python scripts/bench_library.py --frames 10 --only 8 --targets --depth-only``) on 2
cores, one BLAS thread makes detection about a quarter faster. The limit also keeps results independent of how
many threads BLAS would use.

The limit is process-wide (BLAS has no per-thread setting) and is set from the main thread only: OpenBLAS
ignored a setting made from any other thread (measured with numpy's and scipy's OpenBLAS 0.3.30 and 0.3.31), so
called elsewhere the block changes nothing. Blocks nest: the outermost sets the limit and restores what was there.
"""
from __future__ import annotations

import functools
import threading
from contextlib import contextmanager
from typing import Callable, Iterator, TypeVar

F = TypeVar("F", bound=Callable)

_depth = 0
_limiter = None
_controller = None


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """Within the block, the BLAS libraries loaded in this process (numpy's, scipy's) use one thread (on the main
    thread; elsewhere a no-op)."""
    global _depth, _limiter, _controller
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if _depth == 0:
        from threadpoolctl import ThreadpoolController

        if _controller is None:  # finds the loaded BLAS libraries once (numpy and scipy are loaded by now)
            _controller = ThreadpoolController()
        _limiter = _controller.limit(limits=1, user_api="blas")
    _depth += 1
    try:
        yield
    finally:
        _depth -= 1
        if _depth == 0:
            _limiter.restore_original_limits()
            _limiter = None


def on_one_blas_thread(fn: F) -> F:
    """``fn`` run inside ``one_blas_thread()``: for pcdet's entry points (detection, refinement, odometry steps,
    registration), whose products are small. Entering the block costs about 30 microseconds; nested entry
    points cost nothing more."""
    @functools.wraps(fn)
    def limited(*args, **kwargs):
        with one_blas_thread():
            return fn(*args, **kwargs)

    return limited  # type: ignore[return-value]
