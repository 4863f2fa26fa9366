"""The process's thread pools: leaf work split into chunks (:func:`excite.core.parallel.each`) runs
whoever calls it — a task of the evaluator's pool, a chunk of itself — without waiting forever."""

from __future__ import annotations

import threading
import time
from concurrent.futures import wait

import pytest

from excite.core import parallel


def _chunks(out: list, n: int, pause: float = 0.0) -> None:
    def chunk(i: int) -> None:
        time.sleep(pause)
        out[i] = threading.current_thread().name

    parallel.each(chunk, range(n))


def test_each_runs_every_item_on_the_leaf_threads_and_raises_their_error():
    out = [None] * 8
    _chunks(out, 8, 0.01)
    assert all(name.startswith("excite-leaf") for name in out)
    one = [None]
    _chunks(one, 1)
    assert one == [threading.current_thread().name]  # one chunk: inline

    def fails(i: int) -> None:
        if i == 3:
            raise ValueError("chunk 3")

    with pytest.raises(ValueError, match="chunk 3"):
        parallel.each(fails, range(6))


def test_every_task_of_the_shared_pool_may_split_its_work_at_once():
    """Every thread of the evaluator's pool busy with a task that splits its work into chunks
    (a drivable search scoring drives seen in a scene): on that same bounded pool the chunks
    would queue behind the tasks that wait for them, for ever."""
    n = parallel.n_threads()
    busy = threading.Barrier(n, timeout=20)
    outs = [[None] * 4 for _ in range(n)]

    def task(k: int) -> None:
        busy.wait()  # every thread of the pool is running one of these tasks now
        _chunks(outs[k], 4, 0.01)

    futures = [parallel.pool().submit(task, k) for k in range(n)]
    done, pending = wait(futures, timeout=30)
    assert not pending, "the tasks of the shared pool wait for their chunks"
    for f in done:
        f.result()
    assert all(name is not None for out in outs for name in out)


def test_a_chunk_may_split_its_own_work():
    """A chunk that calls :func:`each` again (both leaf threads waiting in it) runs its chunks inline."""
    outs = [[None] * 3 for _ in range(parallel.LEAF_THREADS)]
    both = threading.Barrier(parallel.LEAF_THREADS, timeout=20)

    def outer(k: int) -> None:
        both.wait()  # every leaf thread is in an outer chunk
        _chunks(outs[k], 3)

    result = []
    t = threading.Thread(target=lambda: result.append(parallel.each(outer, range(parallel.LEAF_THREADS))), daemon=True)
    t.start()
    t.join(30)
    assert not t.is_alive(), "the outer chunks wait for inner chunks queued behind them"
    assert all(name is not None and name.startswith("excite-leaf") for out in outs for name in out)
