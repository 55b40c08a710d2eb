"""What the benchmarks share: where the data is, the tuning/test split, a description of the machine."""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path

import cv2
import numpy as np
import scipy

import toosicubix

REPO = Path(__file__).resolve().parents[1]
#: KITTI tracking sequences reserved for tuning (never used for reported accuracy) and for testing.
SPLITS = {
    "tuning": tuple(f"{i:04d}" for i in range(0, 10)),
    "test": tuple(f"{i:04d}" for i in range(10, 21)),
}


def default_data_dir() -> Path:
    """``$TOOSICUBIX_SHARED_DATA``, else ``../shared/data`` beside the repository."""
    env = os.environ.get("TOOSICUBIX_SHARED_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def machine() -> dict[str, str]:
    """CPU, cores, memory and library versions, for the record."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        mem_kb = next(int(ln.split()[1]) for ln in Path("/proc/meminfo").read_text().splitlines()
                      if ln.startswith("MemTotal"))
        memory = f"{mem_kb / 2**20:.0f} GiB"
    except (OSError, StopIteration):
        memory = "unknown"
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                                check=True).stdout.strip()
        changed = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "toosicubix",
                                  "benchmarks/*.py", "pyproject.toml"], cwd=REPO, capture_output=True, text=True,
                                 check=True).stdout.strip()
        if changed:  # figures from code that is not the commit's say so (results and notes do not count)
            commit += "+modified"
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    return {
        "cpu": cpu, "cores": str(os.cpu_count()), "memory": memory, "python": platform.python_version(),
        "numpy": np.__version__, "scipy": scipy.__version__, "opencv": cv2.__version__,
        "toosicubix": toosicubix.__version__, "commit": commit,
    }
