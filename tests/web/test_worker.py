"""The page's background work in a worker process (toosicubix.web.worker)."""

from __future__ import annotations

import os
import signal
from concurrent.futures.process import BrokenProcessPool
from functools import partial

import pytest

from toosicubix.annotations.priors_file import load_priors
from toosicubix.errors import InputFileError
from toosicubix.web.worker import WorkerProcess


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
