"""``rawaug`` command line: each subcommand lives in its own module.

A subcommand module defines ``add_arguments(parser)`` and ``run(args) -> int``.
"""
from __future__ import annotations

import argparse
import importlib
import sys

SUBCOMMANDS = {
    "calibrate": ("rawaug.calibration.command", "measured frames of a camera -> NoiseProfile + report"),
    "loop": ("rawaug.loop.command", "closed loop: diagnose residuals, add missing effects, report before/after"),
    "import-darktable": ("rawaug.calibration.darktable", "a darktable noise profile (the user's noiseprofiles.json) -> NoiseProfile"),
}


def main(argv=None) -> int:
    from . import __version__

    parser = argparse.ArgumentParser(prog="rawaug", description="Low-light raw noise: calibration and closed loop.")
    parser.add_argument("--version", action="version", version=f"rawaug {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    modules = {}
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name and module_name.startswith(exc.name):
                continue  # subcommand not installed in this build
            raise
        modules[name] = module
        module.add_arguments(sub.add_parser(name, help=help_text, description=help_text))
    args = parser.parse_args(argv)
    try:
        return int(modules[args.command].run(args) or 0)
    except (ValueError, OSError) as exc:  # OSError: a file that cannot be read or written
        print(f"rawaug {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
