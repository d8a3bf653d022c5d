"""What a fresh interpreter imports: for tests that keep modules or the command line light."""

from __future__ import annotations

import subprocess
import sys


def modules_loaded_by(code: str) -> set[str]:
    """The modules a new Python process has loaded after running `code` (its stdout is free)."""
    script = code + "\nimport sys\nprint('\\n'.join(sys.modules), file=sys.stderr)\n"
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True
    )
    return set(done.stderr.split())
