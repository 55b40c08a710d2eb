"""The page's background work in a worker process (toosicubix.web.worker)."""

from __future__ import annotations

import os
import signal
import time
from concurrent.futures.process import BrokenProcessPool
from functools import partial

import pytest

from toosicubix.annotations.priors_file import load_priors
from toosicubix.errors import InputFileError
from toosicubix.web.worker import DeadlineWorker, OutOfTime, WorkerDied, WorkerProcess


def test_work_is_done_in_one_other_process_kept_between_calls():
    with WorkerProcess(os.getpid) as worker:
        first = worker()
        assert first != os.getpid()
        assert worker() == first  # kept: the interpreter is started once per session
    assert worker._pool is None  # closed on leaving


def test_an_input_error_in_the_worker_arrives_as_itself(tmp_path):
    missing = tmp_path / "priors.json"
    with WorkerProcess(partial(load_priors, missing)) as worker, pytest.raises(InputFileError) as info:
        worker()
    assert str(missing) in str(info.value) and "cannot read the file" in str(info.value)
    assert info.value.file == str(missing)


def test_a_worker_that_died_is_replaced_on_the_next_call():
    with WorkerProcess(os.getpid) as worker:
        pid = worker()
        os.kill(pid, signal.SIGKILL)
        with pytest.raises(BrokenProcessPool):
            worker()
        assert worker() not in (pid, os.getpid())


# -- the refits' process: an answer within the bound, or the process ended (issue 34, item 4) ----------------------


@pytest.fixture(scope="module")
def deadline_worker():
    with DeadlineWorker() as worker:
        yield worker.start()


def test_a_call_within_its_bound_is_answered_by_a_process_of_its_own(deadline_worker):
    assert deadline_worker.call(abs, (-3,), timeout=5.0) == 3
    assert deadline_worker.call(os.getpid, (), timeout=5.0) != os.getpid()


def test_a_call_over_its_bound_ends_its_process_within_the_bound_and_the_spare_answers_at_once(deadline_worker):
    pid = deadline_worker.call(os.getpid, (), timeout=5.0)
    killed = deadline_worker.killed
    started = time.monotonic()
    with pytest.raises(OutOfTime, match=r"no answer within 0\.3 s"):
        deadline_worker.call(time.sleep, (30,), timeout=0.3)
    late = time.monotonic() - started
    # 0.3 s of waiting, then a SIGKILL and its join (milliseconds): well within a second.
    assert 0.3 <= late < 0.8, late
    assert deadline_worker.killed == killed + 1
    started = time.monotonic()
    assert deadline_worker.call(os.getpid, (), timeout=5.0) not in (pid, os.getpid())
    assert time.monotonic() - started < 0.5  # the spare was warm: no interpreter started for this call


def test_an_exception_in_the_call_arrives_as_itself(deadline_worker):
    with pytest.raises(ValueError, match="invalid literal"):
        deadline_worker.call(int, ("x",), timeout=5.0)
    assert deadline_worker.call(abs, (-1,), timeout=5.0) == 1


def test_a_process_that_died_is_said_and_replaced(deadline_worker):
    pid = deadline_worker.call(os.getpid, (), timeout=5.0)
    with pytest.raises(WorkerDied):
        deadline_worker.call(os.kill, (pid, signal.SIGKILL), timeout=5.0)
    assert deadline_worker.call(os.getpid, (), timeout=5.0) not in (pid, os.getpid())


def _kernel_loaded() -> bool:
    import sys

    return "numba" in sys.modules


def test_warm_names_a_function_to_call_before_the_first_call():
    # The page's fitting process loads the compiled solver before its first refit (issue 37): half a second that
    # would otherwise come out of the first refit's bound, and of the spare's after every kill.
    from toosicubix.solver import compiled
    from toosicubix.web.session import FIT_MODULES

    assert "toosicubix.solver.compiled:warm_up" in FIT_MODULES
    with DeadlineWorker(("toosicubix.web.session",)) as cold:
        assert cold.start().call(_kernel_loaded, (), timeout=30.0) is False
    with DeadlineWorker(FIT_MODULES) as warm:
        assert warm.start().call(_kernel_loaded, (), timeout=30.0) is compiled.available()
