"""The page's work in worker processes of its own: the background estimates, and every refit within a time bound.

The annotate page estimates the click noise and road normals again as its file grows (a pilot fit of up to 400
vehicles, a few seconds). Run in the server's process, that work competes with the page's requests for the
interpreter, which slows the refits the page asks for meanwhile. :class:`WorkerProcess` runs it in one worker
process instead, started on first use by ``spawn`` (a fresh interpreter: none of the server's threads or locks
are copied into it) and kept for the session's later estimates.

:class:`DeadlineWorker` runs the page's refits: each call answers within its time bound or the process computing it
is killed (a thread cannot be stopped; a process can, and its memory goes with it) and :class:`OutOfTime` is
raised. A spare process, started and warmed beforehand, takes over at once, so the next request is not kept
waiting for an interpreter to start.
"""

from __future__ import annotations

import multiprocessing
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.connection import Connection
from typing import Any

__all__ = ["DeadlineWorker", "OutOfTime", "WorkerDied", "WorkerProcess"]


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


class OutOfTime(Exception):
    """A call to a :class:`DeadlineWorker` that did not answer within its time bound (its process was ended), or
    found no warm process to run on within it."""


class WorkerDied(Exception):
    """The worker process ended while computing a call (killed from outside, out of memory); a spare took over."""


class _Process:
    """One worker process and the parent's end of its pipe; ``ready`` once it has imported what it computes with."""

    def __init__(self, context: Any, warm: tuple[str, ...]):
        self.connection, child = context.Pipe()
        self.process = context.Process(target=_serve, args=(child, warm), daemon=True, name="toosicubix-fits")
        self.process.start()
        child.close()
        self.ready = False

    def wait_ready(self, timeout: float) -> bool:
        if not self.ready and self.connection.poll(max(timeout, 0.0)):
            self.connection.recv()  # its first message: warmed
            self.ready = True
        return self.ready

    def end(self) -> None:
        self.process.kill()
        self.process.join(5)
        self.connection.close()


class DeadlineWorker:
    """``function(*args)`` computed in a worker process, answered within ``timeout`` seconds or not at all.

    One process computes, one spare waits, both started by ``spawn`` (fresh interpreters) and warmed by importing
    ``warm`` (module names; ``module:function`` also calls that function of it, without arguments). A call that does
    not answer in time has its process killed (SIGKILL): the spare takes its place at once and a new spare starts.
    Calls are answered one at a time. ``function`` and its arguments and answer must be picklable (module-level
    functions); an exception raised there is raised here. :meth:`close` ends both processes; a later call starts new
    ones.
    """

    def __init__(self, warm: tuple[str, ...] = ()):
        self.warm = warm
        self._context = multiprocessing.get_context("spawn")
        self._lock = threading.Lock()
        self._active: _Process | None = None
        self._spare: _Process | None = None
        #: How many processes were killed for being late, and how many died on their own.
        self.killed = self.died = 0

    def start(self, timeout: float = 60.0) -> DeadlineWorker:
        """Start both processes and wait (up to ``timeout`` seconds) until the computing one is warm."""
        with self._lock:
            self._processes()[0].wait_ready(timeout)
        return self

    def _processes(self) -> tuple[_Process, _Process]:
        if self._active is None:
            self._active = _Process(self._context, self.warm)
        if self._spare is None:
            self._spare = _Process(self._context, self.warm)
        return self._active, self._spare

    def _replace_active(self) -> None:
        """The active process is gone: the spare computes from now on, and a new spare starts."""
        self._active.end()
        self._active, self._spare = self._spare, None
        self._processes()

    def call(self, function: Callable[..., Any], args: tuple, timeout: float) -> Any:
        """``function(*args)`` from the worker, within ``timeout`` seconds.

        Raises
        ------
        OutOfTime
            No answer in time: the process computing it was killed (or none was warm yet, and nothing was sent).
        WorkerDied
            The process ended while computing it.
        """
        deadline = time.monotonic() + timeout
        with self._lock:
            process = self._processes()[0]
            try:
                if not process.wait_ready(deadline - time.monotonic()):
                    raise OutOfTime(f"no fitting process was ready within {timeout:.3g} s (one is starting)")
                process.connection.send((function, args))
                answered = process.connection.poll(max(deadline - time.monotonic(), 0.0))
                if answered:
                    ok, value = process.connection.recv()
            except (EOFError, OSError):
                self.died += 1
                self._replace_active()
                raise WorkerDied("the fitting process ended while computing (killed, or out of memory); another "
                                 "took its place") from None
            if not answered:
                self.killed += 1
                self._replace_active()
                raise OutOfTime(f"no answer within {timeout:.3g} s: the fitting process was ended")
        if not ok:
            raise value
        return value

    def close(self) -> None:
        with self._lock:
            for process in (self._active, self._spare):
                if process is not None:
                    process.end()
            self._active = self._spare = None

    def __enter__(self) -> DeadlineWorker:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _serve(connection: Connection, warm: tuple[str, ...]) -> None:
    """A :class:`DeadlineWorker`'s process: import ``warm`` (and call the functions it names), say so, then answer
    ``(function, args)`` with ``(True, answer)`` or ``(False, exception)`` until the pipe closes."""
    import importlib

    _ignore_interrupts()
    for name in warm:
        module, _, function = name.partition(":")
        imported = importlib.import_module(module)
        if function:
            getattr(imported, function)()
    connection.send("ready")
    while True:
        try:
            function, args = connection.recv()
        except (EOFError, OSError):
            return
        try:
            answer: tuple[bool, Any] = (True, function(*args))
        except Exception as exc:
            answer = (False, exc)
        try:
            connection.send(answer)
        except Exception as exc:  # an answer or exception that does not pickle
            connection.send((False, RuntimeError(f"cannot send the answer back: {type(exc).__name__}: {exc}")))
