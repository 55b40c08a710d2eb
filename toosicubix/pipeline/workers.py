"""How many worker processes a batch takes when asked to choose (``--jobs auto``, the commands' default).

The results never depend on the number (each vehicle is fitted on its own, deterministically, and comes back in
input order), so the choice is one of time alone: one process per usable core, but no more than the batch repays.
A worker costs its start: forked (Linux up to Python 3.13) some tens of milliseconds, since it shares what the main
process has loaded; spawned (macOS, Windows) or started from a fork server (Linux from Python 3.14) it imports the
package and loads the compiled solver itself, about a second. Measured on an AMD EPYC, 2 cores (RESULTS.md, Speed):
with forked workers two processes beat one from 50 simulated KITTI vehicles on (1.14 against 1.35 s whole), with
spawned ones only from some 600 (647: 4.79 against 5.04 s). :data:`VEHICLES_PER_WORKER` asks about twice that of
each worker; :data:`MAX_AUTO` bounds the memory a large machine would spend on workers it cannot feed.
"""

from __future__ import annotations

import math
import multiprocessing
import os
from pathlib import Path

#: ``BatchSettings.jobs`` for "choose": :func:`workers_for` the batch's vehicles.
AUTO = 0
#: Vehicles each worker must have before ``auto`` starts it, by how workers start.
VEHICLES_PER_WORKER = {"fork": 100, "spawn": 1000, "forkserver": 1000}
#: The most workers ``auto`` starts (each holds the solver and its chunk of the batch; more take ``--jobs N``).
MAX_AUTO = 16
#: Linux control groups v2: a container's CPU quota, "max" or "<quota> <period>" in microseconds.
_CPU_MAX = Path("/sys/fs/cgroup/cpu.max")
#: Control groups v1 (older Docker hosts): the quota (-1: none) and the period, microseconds, one file each.
_CFS = Path("/sys/fs/cgroup/cpu")


def usable_cpus() -> int:
    """The cores this process may run on: its CPU affinity (or the machine's count where there is none), bounded by
    a container's CPU quota where Linux states one."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        cpus = os.cpu_count() or 1
    quota = _quota()
    return max(1, min(cpus, quota) if quota else cpus)


def _quota() -> int | None:
    """The cores a Linux container's CPU quota allows (rounded up), or None where none is stated."""
    try:
        fields = _CPU_MAX.read_text().split()
    except OSError:
        try:
            fields = [(_CFS / name).read_text().strip() for name in ("cpu.cfs_quota_us", "cpu.cfs_period_us")]
        except OSError:
            return None
    if len(fields) != 2 or fields[0] == "max":
        return None
    try:
        quota, period = float(fields[0]), float(fields[1])
    except ValueError:
        return None
    return max(1, math.ceil(quota / period)) if quota > 0 and period > 0 else None


def workers_for(n_vehicles: int) -> int:
    """How many processes ``--jobs auto`` fits ``n_vehicles`` with: one per usable core, at most one per
    :data:`VEHICLES_PER_WORKER` vehicles (by how this platform starts workers) and at most :data:`MAX_AUTO`; 1 for a
    batch too small to repay a second."""
    # How workers will start, without fixing it (the platform's default is the first of all methods).
    method = multiprocessing.get_start_method(allow_none=True) or multiprocessing.get_all_start_methods()[0]
    per_worker = VEHICLES_PER_WORKER.get(method, max(VEHICLES_PER_WORKER.values()))
    return max(1, min(usable_cpus(), n_vehicles // per_worker, MAX_AUTO))


def resolved(jobs: int, n_vehicles: int) -> int:
    """``jobs`` as given, or :func:`workers_for` the batch's vehicles when it is :data:`AUTO`."""
    return workers_for(n_vehicles) if jobs == AUTO else jobs
