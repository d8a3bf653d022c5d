"""Command-line entry point. Thin: parse arguments, call the library, map errors to exit codes.

Each subcommand lives in `eurocslam/commands/<name>.py` and exposes `NAME`, `HELP`,
`add_arguments(parser)` and `run(args) -> int`; they are discovered here, so adding a command
touches no other file. Heavy imports (gtsam, cv2) happen inside `run`, keeping `--help` fast.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys
import traceback
from collections.abc import Callable
from types import ModuleType

from eurocslam import __version__
from eurocslam.errors import EurocSlamError

# order in --help; commands not listed here follow alphabetically
_ORDER = ["demo", "run", "convert", "doctor", "synth", "eval", "bench", "play"]


def _commands() -> tuple[list[ModuleType], dict[str, str]]:
    """Command modules in --help order, and the commands that failed to import (a broken
    install: a missing dependency) with the reason, so the rest of the CLI still works."""
    import eurocslam.commands as pkg

    mods: list[ModuleType] = []
    broken: dict[str, str] = {}
    for m in pkgutil.iter_modules(pkg.__path__):
        if m.name.startswith("_"):
            continue
        try:
            mods.append(importlib.import_module(f"eurocslam.commands.{m.name}"))
        except ImportError as e:
            broken[m.name] = f"{type(e).__name__}: {e}"
    rank = {n: i for i, n in enumerate(_ORDER)}
    return sorted(mods, key=lambda m: (rank.get(m.NAME, len(rank)), m.NAME)), broken


def _broken_command(name: str, reason: str) -> Callable[[argparse.Namespace], int]:
    def run(_args: argparse.Namespace) -> int:
        print(
            f"eurocslam {name}: unavailable, this install is incomplete ({reason}); "
            "reinstall with: pip install -e .",
            file=sys.stderr,
        )
        return 3

    return run


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="eurocslam",
        description="Stereo-inertial SLAM for EuRoC MAV data; ROS 2 MCAP in and out, no ROS.",
    )
    parser.add_argument("--version", action="version", version=f"eurocslam {__version__}")
    parser.add_argument(
        "--debug", action="store_true", help="show full tracebacks for internal errors"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    mods, broken = _commands()
    for mod in mods:
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run, _quick_exit=getattr(mod, "QUICK_EXIT", False))
    for name, reason in broken.items():
        p = sub.add_parser(name, help=f"(unavailable: {reason})", add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
        p.set_defaults(_run=_broken_command(name, reason))
    return parser


class _Console(logging.StreamHandler):  # type: ignore[type-arg]
    """Log records as plain lines on whatever `sys.stderr` is when they are emitted."""

    def __init__(self) -> None:
        super().__init__()
        self.setFormatter(logging.Formatter("%(message)s"))

    @property
    def stream(self):  # type: ignore[no-untyped-def]
        return sys.stderr

    @stream.setter
    def stream(self, _value: object) -> None:
        pass


def _console_logging() -> None:
    """The library's log records (notes, warnings) on stderr, set up once per process."""
    log = logging.getLogger("eurocslam")
    if not any(isinstance(h, _Console) for h in log.handlers):
        log.addHandler(_Console())
    log.setLevel(logging.INFO)


def main(argv: list[str] | None = None) -> int:
    """The `eurocslam` command line (`argv`: the arguments; None: this process's own). When it
    is the process's own command line and the command says so (`QUICK_EXIT` in its module: it
    has closed everything it opened), the process ends right after the command, without the
    interpreter freeing every object one by one: after `run` that is the run's maps, graphs and
    arrays (benchmarks/RESULTS.md, SLAM speed: 0.3-2 s of the whole process's time)."""
    _console_logging()
    try:  # a Ctrl-C while the commands load (the first half second) is a Ctrl-C too
        parser = build_parser()
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        print("eurocslam: interrupted", file=sys.stderr)
        return 130
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    code = _call(args)
    if argv is None and getattr(args, "_quick_exit", False):
        _exit_now(code)
    return code


def _call(args: argparse.Namespace) -> int:
    try:
        return int(args._run(args) or 0)
    except EurocSlamError as e:
        one_line = " ".join(str(e).split()) or type(e).__name__
        print(f"eurocslam {args.command}: error: {one_line}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print(f"eurocslam {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1
    except Exception as e:  # a bug: say so plainly, traceback only on request
        if args.debug:
            traceback.print_exc()
        print(
            f"eurocslam {args.command}: internal error: {type(e).__name__}: {e}\n"
            "  (this is a bug in eurocslam; rerun with --debug for the traceback and report it)",
            file=sys.stderr,
        )
        return 3


def _exit_now(code: int) -> None:
    """End the process with `code` once what it printed is out (logging's handlers flushed,
    stdout and stderr written), skipping the interpreter's teardown."""
    logging.shutdown()
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (BrokenPipeError, OSError):
        code = code or 1
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
