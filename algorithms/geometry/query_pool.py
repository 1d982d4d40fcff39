"""Many-point queries split over the cores: one chunk per core on a shared thread pool.

Threads over a serial compiled kernel (which releases the GIL) rather than numba's
``parallel=True``: no slower, and less to compile on the first run.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["PARALLEL_MIN_POINTS", "in_chunks"]

#: From this many points on, a query uses every core (threads cost more than they save
# for a few hundred points).
PARALLEL_MIN_POINTS = 4000

_POOL: ThreadPoolExecutor | None = None


def in_chunks(run: Callable[[int, int], None], n: int) -> None:
    """Call ``run(a, b)`` over the index range ``[0, n)``: in one call below
    :data:`PARALLEL_MIN_POINTS`, else in one chunk per core on the pool's threads."""
    workers = min(_pool_size(), -(-n // PARALLEL_MIN_POINTS))
    if workers <= 1:
        run(0, n)
        return
    bounds = np.linspace(0, n, workers + 1).astype(int).tolist()
    list(_pool().map(lambda k: run(bounds[k], bounds[k + 1]), range(workers)))


def _pool_size() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def _pool() -> ThreadPoolExecutor:
    """The process's query threads, started on first use."""
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=_pool_size(), thread_name_prefix="mesh_index")
    return _POOL
