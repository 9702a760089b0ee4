"""The ``srde-fusion`` command: one parser, every subcommand registered explicitly.

Each subcommand maps its flags to keyword arguments of a library function; the logic
lives in the library. Bad input exits with code 2 and one line on stderr, no traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys

from .. import __version__
from ..errors import SRDEError
from . import calibrate, evaluate, render, scenes, train

__all__ = ["main", "build_parser"]

# Every module here that adds subcommands, in the order ``--help`` lists them. An import
# error in any of them is a bug and surfaces, rather than silently dropping commands.
_COMMAND_MODULES = (render, scenes, evaluate, calibrate, train)


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every subcommand."""
    parser = argparse.ArgumentParser(
        prog="srde-fusion",
        description="Disparity of flat glossy objects from their specular highlight (SRDE), "
        "fused into a neural stereo pipeline.",
    )
    parser.add_argument("--version", action="version", version=f"srde-fusion {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in _COMMAND_MODULES:
        module.register(sub)
    for p in sub.choices.values():
        p.add_argument("-v", "--verbose", action="count", default=0,
                       help="also say every decision (each object's, each check's)")
        if not any("--quiet" in a.option_strings for a in p._actions):
            p.add_argument("--quiet", action="store_true", help="errors only")
    for p in (parser, *sub.choices.values()):
        _one_line_errors(p)
    return parser


def _configure_logging(verbose: int, quiet: bool) -> None:
    """Send the library's log records to stderr at the level the flags ask for."""
    # The library's INFO records are its stage messages (rendering, running the
    # backbone, fusing N objects, writing): the command's progress, shown by default on
    # a terminal. Piped or redirected, stderr stays for warnings and the one-line error.
    if quiet:
        level = logging.ERROR
    elif verbose >= 1:
        level = logging.DEBUG
    else:
        level = logging.INFO if sys.stderr.isatty() else logging.WARNING
    logger = logging.getLogger("srde_fusion")
    logger.setLevel(level)
    if not any(isinstance(h, _StderrHandler) for h in logger.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("srde-fusion: %(message)s"))
        logger.addHandler(handler)


class _StderrHandler(logging.StreamHandler):
    """A handler writing to whatever ``sys.stderr`` is when a record is emitted."""

    @property
    def stream(self):  # noqa: D102
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:
        pass


def _one_line_errors(parser: argparse.ArgumentParser) -> None:
    """Make a parser's argument errors one line on stderr, exit code 2, no usage block."""

    def error(message: str) -> None:
        parser.exit(2, f"{parser.prog}: error: {message}\n")

    parser.error = error  # type: ignore[method-assign]


def main(argv: list[str] | None = None) -> int:
    """Run the command; returns the exit code (0 ok, 1 some scenes failed, 2 bad input)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    _configure_logging(args.verbose, args.quiet)
    try:
        result = args.func(args)
    except SRDEError as exc:
        print(f"srde-fusion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # an output the system refuses (a folder in the way, disk full)
        print(f"srde-fusion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    return int(result or 0)
