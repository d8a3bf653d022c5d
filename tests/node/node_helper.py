"""Run tests/node/decode_mcap.mjs (what Foxglove does with a file) from Python tests.

The npm packages are installed once into a cache (`EUROCSLAM_NODE_CACHE`, default
~/.cache/eurocslam-node). Tests skip cleanly when node/npm are missing or the install fails
(offline machine without the cache)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

SCRIPT = Path(__file__).with_name("decode_mcap.mjs")
PACKAGES = {
    "@mcap/core": "2.2.2",
    "@mcap/support": "1.1.0",
    "@foxglove/rosmsg": "5.0.5",
    "@foxglove/rosmsg2-serialization": "3.1.0",
}


def cache_dir() -> Path:
    default = Path.home() / ".cache" / "eurocslam-node"
    return Path(os.environ.get("EUROCSLAM_NODE_CACHE", default))


def node_modules() -> Path:
    """The node_modules folder with the packages; installs them on first use, or skips."""
    if shutil.which("node") is None or shutil.which("npm") is None:
        pytest.skip("node/npm not available")
    d = cache_dir()
    mods = d / "node_modules"
    if all((mods / p / "package.json").exists() for p in PACKAGES):
        return mods
    d.mkdir(parents=True, exist_ok=True)
    if not (d / "package.json").exists():
        (d / "package.json").write_text('{"name": "eurocslam-node-check", "private": true}\n')
    specs = [f"{p}@{v}" for p, v in PACKAGES.items()]
    r = subprocess.run(
        ["npm", "install", "--no-audit", "--no-fund", "--prefix", str(d), *specs],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    if r.returncode != 0:
        pytest.skip(f"npm install failed (offline?): {r.stderr.strip()[-300:]}")
    return mods


def decode(mcap: Path) -> tuple[int, dict, str]:
    """(exit code, parsed JSON summary or {}, stderr) of decode_mcap.mjs on `mcap`."""
    env = dict(os.environ, NODE_PATH=str(node_modules()))
    r = subprocess.run(
        ["node", str(SCRIPT), str(mcap)],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )
    out = json.loads(r.stdout.strip().splitlines()[-1]) if r.returncode == 0 else {}
    return r.returncode, out, r.stderr
