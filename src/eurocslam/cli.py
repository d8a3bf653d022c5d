"""Command-line entry point. Thin: parse arguments, call the library, map errors to exit codes.

Each subcommand lives in `eurocslam/commands/<name>.py` and exposes `NAME`, `HELP`,
`add_arguments(parser)` and `run(args) -> int`; they are discovered here, so adding a command
touches no other file. Heavy imports (gtsam, cv2) happen inside `run`, keeping `--help` fast.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
import traceback
from types import ModuleType

from eurocslam import __version__
from eurocslam.errors import EurocSlamError

# order in --help; commands not listed here follow alphabetically
_ORDER = ["demo", "run", "convert", "doctor", "synth", "eval", "bench", "play"]


def _commands() -> list[ModuleType]:
    import eurocslam.commands as pkg

    mods = [
        importlib.import_module(f"eurocslam.commands.{m.name}")
        for m in pkgutil.iter_modules(pkg.__path__)
        if not m.name.startswith("_")
    ]
    rank = {n: i for i, n in enumerate(_ORDER)}
    return sorted(mods, key=lambda m: (rank.get(m.NAME, len(rank)), m.NAME))


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
    for mod in _commands():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
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


if __name__ == "__main__":
    sys.exit(main())
