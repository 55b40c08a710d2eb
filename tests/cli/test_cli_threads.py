"""The command's processes run one BLAS thread each (``--jobs`` gives the parallelism), unless the user says
otherwise in the environment."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

CODE = "import os, toosicubix.cli; print(os.environ.get('OPENBLAS_NUM_THREADS'), os.environ.get('MKL_NUM_THREADS'))"


def _run(env: dict[str, str]) -> str:
    return subprocess.run([sys.executable, "-c", CODE], capture_output=True, text=True, check=True, env=env).stdout


def test_one_blas_thread_by_default():
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    assert _run(env).split() == ["1", "1"]


@pytest.mark.parametrize("threads", ["4", "0"])
def test_a_value_the_user_set_wins(threads):
    env = {**os.environ, "OPENBLAS_NUM_THREADS": threads, "MKL_NUM_THREADS": threads}
    assert _run(env).split() == [threads, threads]


def test_set_before_numpy_loads():
    """The setting only counts if numpy (and its OpenBLAS) is not loaded before it: importing the command loads
    it only after."""
    code = ("import sys, builtins\n"
            "seen = []\n"
            "real = builtins.__import__\n"
            "def spy(name, *a, **k):\n"
            "    if name == 'numpy' and 'numpy' not in sys.modules:\n"
            "        import os; seen.append(os.environ.get('OPENBLAS_NUM_THREADS'))\n"
            "    return real(name, *a, **k)\n"
            "builtins.__import__ = spy\n"
            "import toosicubix.cli\n"
            "print(seen[:1])\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert out.strip() == "['1']"
