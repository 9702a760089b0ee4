"""The ``srde-fusion`` command line.

Owns every ``argparse`` parser of the project and is the only part of the core that
imports :mod:`srde_fusion.adapters` (to load backbones by name). Each module adds the
subcommands of one concern; handlers map flags to keyword arguments of library
functions and print what those return.
"""

from .main import build_parser, main

__all__ = ["main", "build_parser"]
