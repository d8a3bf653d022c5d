"""Outputs written beside the previous ones and swapped in at the end.

A run writes into `OUT/.staging/`; only once every output is complete are they moved into `OUT`
(each file replaced in one `os.replace`), and a previous run's outputs that this run does not
produce are removed then. A run that fails leaves `OUT` as it was, apart from the interrupted
MCAP (`run.mcap.partial`, readable) when the run had started writing frames.
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
from collections.abc import Iterable
from pathlib import Path

from eurocslam.errors import OutputError

logger = logging.getLogger(__name__)

STAGING = ".staging"


class StagedOutputs:
    """`OUT/.staging/` while the run writes; `commit` swaps its files into `OUT`."""

    def __init__(self, out_dir: Path, known_names: Iterable[str]) -> None:
        self.out_dir = out_dir
        self.known_names = tuple(known_names)  # every output a run may leave in OUT
        self._created_out = not out_dir.exists()
        self.dir = out_dir / STAGING
        try:
            out_dir.mkdir(parents=True, exist_ok=True)
            if self.dir.exists():  # left by a run that was killed
                shutil.rmtree(self.dir)
            self.dir.mkdir()
        except OSError as e:
            raise OutputError(f"{out_dir}: cannot create the output folder: {e}") from None

    def commit(self) -> None:
        """Move every staged output into OUT; remove a previous run's outputs this run did not
        write (a run.mcap when this one had --no-mcap, say)."""
        new = {p.name for p in self.dir.iterdir()}
        old = [n for n in self.known_names if n not in new and (self.out_dir / n).exists()]
        replaced = [n for n in self.known_names if n in new and (self.out_dir / n).exists()]
        if old or replaced:
            logger.info(
                "note: replacing the outputs of a previous run in %s (%s)",
                self.out_dir,
                ", ".join(sorted({*old, *replaced})),
            )
        try:
            for name in sorted(new):
                dst = self.out_dir / name
                if dst.is_dir() and not dst.is_symlink():
                    shutil.rmtree(dst)
                os.replace(self.dir / name, dst)
            for name in old:
                p = self.out_dir / name
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                else:
                    p.unlink()
        except OSError as e:
            raise OutputError(
                f"{self.out_dir}: cannot move the new outputs in place: {e}"
            ) from None
        with contextlib.suppress(OSError):
            self.dir.rmdir()

    def abandon(self, keep: Iterable[str] = ()) -> list[Path]:
        """The run failed: drop the staged outputs but `keep` (moved into OUT); OUT is as it
        was otherwise (and gone again if this run created it empty). Returns the kept paths."""
        kept = []
        for name in keep:
            src = self.dir / name
            if src.exists():
                with contextlib.suppress(OSError):
                    os.replace(src, self.out_dir / name)
                    kept.append(self.out_dir / name)
        shutil.rmtree(self.dir, ignore_errors=True)
        if self._created_out:
            with contextlib.suppress(OSError):
                self.out_dir.rmdir()  # only if empty
        return kept
