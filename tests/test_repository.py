"""What the repository holds: nothing that only works on the machine it was committed from."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_no_symbolic_links_are_committed() -> None:
    """A link committed from a worktree (a `.venv` pointing at a shared environment) breaks every
    fresh clone: `.ci/run` could not create its own virtual environment."""
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout")
    r = subprocess.run(["git", "ls-files", "-s"], cwd=REPO, capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"git ls-files failed: {r.stderr.strip()}")
    links = [line.split("\t", 1)[1] for line in r.stdout.splitlines() if line.startswith("120000")]
    assert not links, links
