"""The process's thread pools: one for the evaluator's parallel stages (sampling, linearising,
assembling: :func:`pool`), one for leaf work split into chunks (casting a scene's rays:
:func:`each`). numpy, Embree and the compiled kernels release the GIL in their loops."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")

_POOL: tuple[int, ThreadPoolExecutor] | None = None
_LEAVES: tuple[int, ThreadPoolExecutor] | None = None
_LOCK = threading.Lock()
_ON_LEAF = threading.local()

LEAF_THREADS = 2
"""Threads running the chunks of :func:`each` at once (in the whole process)."""


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


def _mark_leaf() -> None:
    _ON_LEAF.active = True


def _leaf_pool() -> ThreadPoolExecutor:
    global _LEAVES
    with _LOCK:
        if _LEAVES is None or _LEAVES[0] != os.getpid():
            _LEAVES = (os.getpid(), ThreadPoolExecutor(max_workers=LEAF_THREADS, thread_name_prefix="excite-leaf",
                                                       initializer=_mark_leaf))
        return _LEAVES[1]


def each(fn: Callable[[T], object], items: Iterable[T]) -> None:
    """Call ``fn`` on every item, :data:`LEAF_THREADS` at a time, and return when all are done
    (the first exception raised, if any). ``fn`` is leaf work (a chunk of rays cast and summed
    into its own slice of the output): it must not wait for other tasks.

    The chunks run on a pool of their own, never on :func:`pool`: a caller may itself be a task
    of that pool (a drivable search's scorer, a chunk of the evaluator), and a task that waits for
    tasks queued behind it on the same bounded pool waits forever once every thread does. Called
    from within a chunk (a leaf of a leaf), or with one item, it runs inline."""
    items = list(items)
    if len(items) <= 1 or getattr(_ON_LEAF, "active", False):
        for x in items:
            fn(x)
        return
    list(_leaf_pool().map(fn, items))
