"""The page's background work in a worker process of its own.

The annotate page estimates the click noise and road normals again as its file grows (a pilot fit of up to 400
vehicles, a few seconds). Run in the server's process, that work competes with the page's requests for the
interpreter, which slows the refits the page asks for meanwhile. :class:`WorkerProcess` runs it in one worker
process instead, started on first use by ``spawn`` (a fresh interpreter: none of the server's threads or locks
are copied into it) and kept for the session's later estimates.
"""

from __future__ import annotations

import multiprocessing
import signal
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

__all__ = ["WorkerProcess"]


class WorkerProcess:
    """``function(*args)`` computed in one worker process; calling it waits for the answer, and an exception
    raised there is raised here (input errors arrive as themselves). ``function`` and its arguments must be
    picklable (a module-level function, or a ``functools.partial`` of one). :meth:`close` ends the worker; a
    later call starts a new one."""

    def __init__(self, function: Callable[..., Any]):
        self.function = function
        self._pool: ProcessPoolExecutor | None = None

    def __call__(self, *args: Any) -> Any:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=_ignore_interrupts)
        try:
            return self._pool.submit(self.function, *args).result()
        except BrokenProcessPool:  # the worker died (killed, out of memory): the next call starts a new one
            self.close()
            raise

    def close(self) -> None:
        """End the worker, without waiting for work it is doing (the page is shutting down)."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    def __enter__(self) -> WorkerProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _ignore_interrupts() -> None:
    # Ctrl-C reaches the terminal's whole process group: the server stops and ends the worker, which must not
    # die of it first with a traceback of its own.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
