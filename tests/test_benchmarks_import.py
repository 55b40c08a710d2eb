"""Every benchmark script imports: a name one of them takes from another (or from the package) that is renamed
or removed fails here, not on the next person's benchmark run."""

from __future__ import annotations

import importlib
import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.mark.parametrize("script", sorted(p.stem for p in BENCHMARKS.glob("*.py")))
def test_benchmark_imports(script, monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    module = importlib.import_module(script)
    if script != "common":  # the helpers the scripts share
        assert callable(getattr(module, "main", None)), f"benchmarks/{script}.py has no main()"
    monkeypatch.delitem(sys.modules, script)
