"""``--jobs auto`` (the default of fit, validate and tune): how many processes a batch takes, and that the choice
never shows in the results."""

from __future__ import annotations

import json
import logging
import os

import pytest
from click.testing import CliRunner

from tests.pipeline.test_fit_file_workers import _file, _pids
from toosicubix.cli import main
from toosicubix.pipeline import fitting, workers


@pytest.fixture
def machine(monkeypatch):
    """Set the usable cores and how workers start: ``machine(cores, method)``."""

    def set_to(cores: int, method: str) -> None:
        monkeypatch.setattr(workers, "usable_cpus", lambda: cores)
        monkeypatch.setattr(workers.multiprocessing, "get_start_method", lambda allow_none=False: method)

    return set_to


@pytest.mark.parametrize(("cores", "method", "vehicles", "expected"), [
    (8, "fork", 99, 1),  # too few to repay a second process
    (8, "fork", 250, 2),  # one per 100 vehicles
    (8, "fork", 5000, 8),  # one per core
    (64, "fork", 10**6, 16),  # at most MAX_AUTO
    (8, "spawn", 900, 1),  # a spawned worker costs a second: one per 1,000 vehicles
    (8, "spawn", 3500, 3),
    (8, "forkserver", 3500, 3),
    (1, "fork", 10**6, 1),  # one core: one process
])
def test_auto_takes_a_process_per_core_the_batch_repays(machine, cores, method, vehicles, expected):
    machine(cores, method)
    assert workers.workers_for(vehicles) == expected
    assert workers.resolved(workers.AUTO, vehicles) == expected
    assert workers.resolved(3, vehicles) == 3  # a number given is a number taken


@pytest.mark.parametrize(("text", "quota"), [("max 100000", None), ("150000 100000", 2), ("50000 100000", 1),
                                             ("400000 100000", 4), ("garbage", None), ("0 100000", None)])
def test_a_containers_cpu_quota_bounds_the_cores(tmp_path, monkeypatch, text, quota):
    cpu_max = tmp_path / "cpu.max"
    cpu_max.write_text(text + "\n")
    monkeypatch.setattr(workers, "_CPU_MAX", cpu_max)
    assert workers._quota() == quota
    if quota is not None:
        assert workers.usable_cpus() <= quota
    monkeypatch.setattr(workers, "_CPU_MAX", tmp_path / "absent")
    monkeypatch.setattr(workers, "_CFS", tmp_path / "absent-too")
    assert workers._quota() is None and workers.usable_cpus() >= 1


@pytest.mark.parametrize(("quota_us", "expected"), [("-1", None), ("250000", 3), ("100000", 1)])
def test_a_cgroup_v1_quota_counts_too(tmp_path, monkeypatch, quota_us, expected):
    (tmp_path / "cpu.cfs_quota_us").write_text(quota_us + "\n")
    (tmp_path / "cpu.cfs_period_us").write_text("100000\n")
    monkeypatch.setattr(workers, "_CPU_MAX", tmp_path / "no-v2")
    monkeypatch.setattr(workers, "_CFS", tmp_path)
    assert workers._quota() == expected


def test_the_default_fits_in_several_processes_with_the_bytes_of_one(tmp_path, machine, monkeypatch):
    machine(2, "fork")
    monkeypatch.setitem(workers.VEHICLES_PER_WORKER, "fork", 5)  # the sample three times over: 18 vehicles
    path = _file(tmp_path)
    auto = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "auto")])
    one = CliRunner().invoke(main, ["fit", str(path), "-o", str(tmp_path / "one"), "--jobs", "1"])
    assert auto.exit_code == one.exit_code == 0, auto.output + one.output
    assert "(2 processes)" in auto.output and "processes)" not in one.output
    for name in ["results.json", *sorted(p.name for p in (tmp_path / "one" / "label_2").iterdir())]:
        where = "" if name == "results.json" else "label_2"
        assert (tmp_path / "one" / where / name).read_bytes() == (tmp_path / "auto" / where / name).read_bytes()
    assert json.loads((tmp_path / "auto" / "results.json").read_text())["images"]


@pytest.mark.parametrize("given", ["0", "-2", "two", ""])
def test_jobs_takes_a_number_or_auto(tmp_path, given):
    result = CliRunner().invoke(main, ["fit", str(_file(tmp_path)), "-o", str(tmp_path / "o"), "--jobs", given])
    assert result.exit_code == 2
    assert "expected a number of processes (1 or more) or 'auto'" in result.output


def _no_pools(jobs):
    raise OSError(38, "Function not implemented")  # what a platform without POSIX semaphores says


def test_without_process_pools_the_batch_runs_in_one_process(monkeypatch, caplog):
    monkeypatch.setattr(fitting, "_new_pool", _no_pools)
    tasks = [(k,) for k in range(7)]
    with caplog.at_level(logging.WARNING, logger="toosicubix.pipeline.fitting"):
        done = list(fitting.ordered_map(iter(tasks), 2, 3, _pids))
    assert [t for t, _ in done] == tasks and len({pid for _, pid in done}) == 1 and done[0][1] == os.getpid()
    assert "cannot start 2 worker processes (OSError" in caplog.text and "same results" in caplog.text


def test_without_process_pools_a_batch_says_so_once(monkeypatch, caplog):
    """A batch's passes (its pilot, then its fits) share the block: the first finds that pools cannot start, the
    others run in this process without trying again."""
    tries = []
    monkeypatch.setattr(fitting, "_new_pool", lambda jobs: tries.append(jobs) or _no_pools(jobs))
    tasks = [(k,) for k in range(5)]
    with caplog.at_level(logging.WARNING, logger="toosicubix.pipeline.fitting"), fitting.shared_workers():
        passes = [list(fitting.ordered_map(iter(tasks), 2, 2, _pids)) for _ in range(3)]
    assert all([t for t, _ in done] == tasks for done in passes)
    assert tries == [2] and caplog.text.count("cannot start 2 worker processes") == 1


def _interrupt_handler(tasks: list) -> list:
    """A chunk's tasks, each with what its worker does on Ctrl-C (SIGINT)."""
    import signal

    return [(task, signal.getsignal(signal.SIGINT) is signal.SIG_IGN) for task in tasks]


def test_workers_leave_ctrl_c_to_the_main_process():
    """Ctrl-C reaches the terminal's whole process group. The main process stops the batch; a worker interrupted
    inside the compiled solver would report it broken (and fall back to numpy) before being shut down."""
    import signal

    done = list(fitting.ordered_map(iter([(k,) for k in range(6)]), 2, 2, _interrupt_handler))
    assert [ignored for _, ignored in done] == [True] * 6
    assert signal.getsignal(signal.SIGINT) is not signal.SIG_IGN  # the main process still takes it
