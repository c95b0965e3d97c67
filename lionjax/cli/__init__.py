"""The ``lionjax`` command line: one subcommand per module in this package.

Each subcommand module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``
(returning an exit code). Errors of bad input (:class:`lionjax.InputError`) and failed
identifications are printed as one readable line and exit with status 2.
"""

from __future__ import annotations

import argparse
import importlib
import re
import sys

SUBCOMMANDS = ("identify", "reproduce", "diagnose", "study")


def _enable_x64() -> None:
    # Identification on real records needs float64 (positions of 0.2 m resolved to 50 nm).
    import jax

    jax.config.update("jax_enable_x64", True)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lionjax",
        description="Identify device dynamics with Lion's method and diagnose the sim-to-real gap.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        mod = importlib.import_module(f"lionjax.cli._{name}")
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.__doc__)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--regions -0.01,0.01`` → ``--regions=-0.01,0.01`` (argparse reads '-0.01,…' as a flag)."""
    out: list[str] = []
    i = 0
    while i < len(argv):
        a = argv[i]
        nxt = argv[i + 1] if i + 1 < len(argv) else ""
        if a.startswith("--") and "=" not in a and re.match(r"^-[\d.]", nxt):
            out.append(f"{a}={nxt}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def main(argv: list[str] | None = None) -> int:
    _enable_x64()
    from .._errors import IdentificationError, InputError

    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(_join_negative_values(argv))
    if args.version:
        from .. import __version__

        print(__version__)
        return 0
    if args.command is None:
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except (InputError, IdentificationError) as e:
        print(f"lionjax {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"lionjax {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
