"""The page's fuzz target (benchmarks/fuzz_page.py): a live annotate server, a few mutated requests, and what the
harness counts on them."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"


@pytest.fixture
def page_target(monkeypatch, tmp_path):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    for name in ("fuzz", "fuzz_targets", "fuzz_page"):  # fresh: another test may have imported some of them
        sys.modules.pop(name, None)
    import fuzz_targets

    target = fuzz_targets.TARGETS["page"]()
    target.prepare(tmp_path)
    try:
        yield target
    finally:
        if target.server.poll() is None:
            target.server.kill()
            target.server.wait(10)
        for name in ("fuzz", "fuzz_targets", "fuzz_page"):
            sys.modules.pop(name, None)


def test_mutated_requests_to_a_live_server_are_answered_and_counted(page_target, tmp_path):
    records = []
    for index in range(40):
        folder = tmp_path / f"c{index}"
        folder.mkdir()
        records += page_target.run_case(index, 0, folder, 5.0, None)
    records += page_target.finish()
    statuses = [r["status"] for r in records if isinstance(r.get("status"), int)]
    validated = [r["status"] for r in records if r["command"] == "validate the file"]
    assert validated in (["exit 0"], ["exit 1"])  # the file the requests left, read by validate
    assert len(statuses) == 41  # 40 requests, and the one after the run
    assert all(s is not None and s < 500 for s in statuses), statuses
    assert not any(r.get(k) for r in records for k in ("traceback", "non_finite", "unreadable", "signal",
                                                       "harness_error")), records
    assert any(s == 200 for s in statuses) and any(400 <= s < 500 for s in statuses)  # both kinds were sent
    assert page_target.summary["requests"] == 40 and page_target.summary["peak_server_mb"] > 0
    assert page_target.server.poll() is not None  # stopped by finish
