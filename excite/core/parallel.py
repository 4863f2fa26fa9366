"""The process's thread pool for the evaluator's parallel stages (sampling, linearising,
assembling): numpy and the compiled kernels release the GIL in their loops."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

_POOL: tuple[int, ThreadPoolExecutor] | None = None


def n_threads() -> int:
    """Threads of the pool: one per core, at most four."""
    return max(1, min(4, os.cpu_count() or 1))


def pool() -> ThreadPoolExecutor:
    """A thread pool of this process (re-created after a fork: threads do not survive it)."""
    global _POOL
    if _POOL is None or _POOL[0] != os.getpid():
        _POOL = (os.getpid(), ThreadPoolExecutor(max_workers=n_threads(),
                                                 thread_name_prefix="excite"))
    return _POOL[1]

