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


class hidden_main:
    """Within it, processes started by the ``spawn`` method do not re-run the parent's
    ``__main__`` script (a spawned child imports it unless it is hidden: a script calling the
    library without an ``if __name__ == "__main__"`` guard would run again in it). Submit the
    tasks that start a spawned pool's processes inside it; the tasks must live in importable
    modules."""

    def __enter__(self) -> "hidden_main":
        import sys

        self.main = sys.modules["__main__"]
        self.hidden = {k: self.main.__dict__.get(k) for k in ("__file__", "__spec__") if k in self.main.__dict__}
        self.main.__dict__.pop("__file__", None)
        self.main.__spec__ = None
        return self

    def __exit__(self, *exc) -> None:
        self.main.__dict__.pop("__spec__", None)
        self.main.__dict__.update(self.hidden)
