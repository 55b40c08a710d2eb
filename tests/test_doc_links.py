"""Every relative link and #anchor in the README, docs/ and the benchmark documents points somewhere that exists.

Anchors are matched as GitHub makes them from headings (lower case, punctuation dropped, spaces to hyphens, a
repeated heading numbered -1, -2, ...) or given explicitly as ``<a id="...">``. Links with a scheme (https:,
mailto:) are not followed: the test needs no network.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from tests.conftest import REPO

DOCUMENTS = sorted([REPO / "README.md", *(REPO / "docs").glob("*.md"),
                    REPO / "benchmarks" / "RESULTS.md", REPO / "benchmarks" / "decisions.md"])

_FENCE = re.compile(r"^\s*(```|~~~)")
_CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HTML_ANCHOR = re.compile(r"<a\s+(?:id|name)=\"([^\"]+)\"", re.IGNORECASE)
_HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")


def _prose_lines(text: str) -> list[str]:
    """The lines outside fenced code blocks."""
    lines, fenced = [], False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            lines.append(line)
    return lines


def slug(heading: str) -> str:
    """GitHub's anchor for a heading's text."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link keeps its text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """Every anchor a link into ``path`` may name."""
    found: set[str] = set()
    counts: dict[str, int] = {}
    for line in _prose_lines(path.read_text(encoding="utf-8")):
        found.update(_HTML_ANCHOR.findall(line))
        heading = _HEADING.match(line)
        if heading:
            base = slug(heading.group(2))
            n = counts.get(base, 0)
            counts[base] = n + 1
            found.add(base if n == 0 else f"{base}-{n}")
    return found


def links(path: Path) -> list[str]:
    """The link targets in ``path``'s prose (not in code)."""
    targets = []
    for line in _prose_lines(path.read_text(encoding="utf-8")):
        targets.extend(_LINK.findall(_CODE_SPAN.sub("", line)))
    return targets


def broken_links(path: Path) -> list[str]:
    """The relative links of ``path`` whose file or anchor does not exist, each with why."""
    broken = []
    for target in links(path):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.IGNORECASE):
            continue  # https:, mailto:, ...: not followed
        file_part, _, anchor = target.partition("#")
        destination = (path.parent / file_part).resolve() if file_part else path
        if not destination.exists():
            broken.append(f"{target}: no file {destination}")
        elif anchor and destination.suffix == ".md" and anchor not in anchors(destination):
            broken.append(f"{target}: no heading or anchor #{anchor} in {destination.name}")
    return broken


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_and_anchor_resolves(path):
    assert path.exists()
    assert broken_links(path) == []


def test_slugs_follow_github():
    assert slug("Annotating: `toosicubix annotate`") == "annotating-toosicubix-annotate"
    assert slug("Real human clicks: ApolloCar3D (`benchmarks/apollocar3d.py`, issue 14)") == (
        "real-human-clicks-apollocar3d-benchmarksapollocar3dpy-issue-14")
    assert slug("The robust loss on real clicks (rule 18): `--robust-loss auto` is the default") == (
        "the-robust-loss-on-real-clicks-rule-18---robust-loss-auto-is-the-default")
    assert slug("What issue 14's E_R target asks") == "what-issue-14s-e_r-target-asks"


def test_a_broken_link_is_found(tmp_path):
    (tmp_path / "other.md").write_text("# Other page\n\n## A section\n")
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n[fine](other.md#a-section) [also fine](#page) `[in code](missing.md)`\n\n"
                    "```\n[in a block](missing.md)\n```\n\n"
                    "[no file](missing.md) [no anchor](other.md#nowhere) [web](https://example.org/x.md)\n")
    assert broken_links(page) == [
        f"missing.md: no file {tmp_path / 'missing.md'}",
        "other.md#nowhere: no heading or anchor #nowhere in other.md",
    ]
