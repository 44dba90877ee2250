"""Docs state what is: no commit hashes and no times of day in ``docs/`` or the README (dated runs
and comparisons of commits live in ``results/``), and no claim that a served route is missing."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = [*sorted((ROOT / "docs").glob("*.md")), ROOT / "README.md"]
HEX = re.compile(r"\b[0-9a-f]{7,40}\b")
TIME_OF_DAY = re.compile(r"\b([01]\d|2[0-3]):[0-5]\d\b")


def commits_among(tokens: set[str]) -> set[str]:
    """The tokens that name a commit of this repository (none where git or history is absent)."""
    if not tokens:
        return set()
    try:
        out = subprocess.run(
            ["git", "cat-file", "--batch-check"],
            input="".join(f"{t}^{{commit}}\n" for t in sorted(tokens)),
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=30,
        )
    except (OSError, subprocess.TimeoutExpired):
        return set()
    found = set()
    for token, line in zip(sorted(tokens), out.stdout.splitlines(), strict=False):
        if line.split()[1:2] == ["commit"]:
            found.add(token)
    return found


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_no_commit_hashes_or_times_of_day(path: Path) -> None:
    text = path.read_text()
    hashes = commits_among({m.group(0) for m in HEX.finditer(text) if not m.group(0).isdigit()})
    assert not hashes, f"{path.name} names commits {sorted(hashes)}: put dated runs in results/"
    times = sorted({m.group(0) for m in TIME_OF_DAY.finditer(text)})
    assert not times, f"{path.name} names times of day {times}: put dated runs in results/"


def test_the_scan_finds_a_commit_of_this_repository() -> None:
    head = subprocess.run(
        ["git", "rev-parse", "--short=7", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    if not head:
        pytest.skip("no git history here")
    assert commits_among({head, "0a1e6f0a"}) == {head}
    assert TIME_OF_DAY.search("run at 18:47") and not TIME_OF_DAY.search("ratio 3.5:1")


def test_api_md_claims_no_served_route_missing() -> None:
    from service.api.app import app

    text = (ROOT / "docs" / "api.md").read_text()
    missing = text[text.index("## Not implemented") :] if "## Not implemented" in text else ""
    for path in app.openapi()["paths"]:
        assert f"`{path}`" not in missing and f"{path}`" not in missing, path
    assert "coverage audit" not in missing
