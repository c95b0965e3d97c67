"""The ``lionjax`` command line: one subcommand per module in this package.

Each subcommand module defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and ``run(args)``
(returning an exit code). Every error goes through one handler (:func:`main`): bad input
(:class:`lionjax.InputError`), a failed identification, an unwritable output file, a bad option,
and — a bug — any other exception, is printed as one line ``lionjax COMMAND: error: …`` naming
the file or option and the fix, and exits with status 2; never a traceback (set the environment
variable ``LIONJAX_TRACEBACK=1`` to get one for a bug report). Warnings (a probable unit mistake,
a filter fast for the sampling) are printed as one line ``lionjax COMMAND: warning: …``.

Every subcommand keeps its compiled programs in JAX's persistent compilation cache, so that a
second process starts warm (:mod:`._compile_cache`: the folder, and the opt-out
``--no-compile-cache`` / ``LIONJAX_NO_COMPILE_CACHE=1``), and on glibc keeps freed memory below
32 MiB for reuse instead of returning it to the kernel (:mod:`._heap`: page faults took a quarter
of a compiled diagnosis' time).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import warnings

#: Exit status of every error (bad input or options, failed identification, unwritable output).
EXIT_ERROR = 2

SUBCOMMANDS = ("identify", "reproduce", "diagnose", "study")


def _enable_x64() -> None:
    # Identification on real records needs float64 (positions of 0.2 m resolved to 50 nm).
    import jax

    jax.config.update("jax_enable_x64", True)


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of the other errors (and a pointer to --help)."""

    def error(self, message: str):
        print(
            f"{self.prog}: error: {message} (see '{self.prog} --help')",
            file=sys.stderr,
        )
        raise SystemExit(EXIT_ERROR)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lionjax",
        description="Identify device dynamics with Lion's method and diagnose the sim-to-real gap.",
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    _no_cache_flag(parser, False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in SUBCOMMANDS:
        mod = importlib.import_module(f"lionjax.cli._{name}")
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.__doc__)
        mod.add_arguments(p)
        p.add_argument(
            "--quiet",
            action="store_true",
            help="no progress on stderr (default: drawn where stderr is a terminal, once a step "
            "has run 2 s)",
        )
        _no_cache_flag(p, argparse.SUPPRESS)  # also after the command; keeps one given before
        p.set_defaults(_run=mod.run)
    return parser


def _no_cache_flag(p: argparse.ArgumentParser, default) -> None:
    """``--no-compile-cache``: listed by ``lionjax --help``; also accepted after the command
    (unlisted there, and ``default`` SUPPRESS keeps a flag given before the command)."""
    p.add_argument(
        "--no-compile-cache",
        action="store_true",
        default=default,
        help=argparse.SUPPRESS
        if default is argparse.SUPPRESS
        else "do not keep compiled programs on disk (default: kept in $LIONJAX_CACHE_DIR, else "
        "$XDG_CACHE_HOME/lionjax/jax or ~/.cache/lionjax/jax; LIONJAX_NO_COMPILE_CACHE=1 also "
        "turns it off)",
    )


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
    """Run ``lionjax ARGV``; returns the exit status (0 success, 1 some records of a batch not
    identified, 2 an error, 130 interrupted). Errors print one line and never a traceback."""
    from ._heap import keep_freed_memory

    keep_freed_memory()
    _enable_x64()
    from .._io import cli_hints

    parser = build_parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(_join_negative_values(argv))
    if args.version:
        from .. import __version__

        print(__version__)
        return 0
    if args.command is None:
        parser.print_help()
        return EXIT_ERROR
    name = f"lionjax {args.command}"
    token = cli_hints.set(True)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("always", UserWarning)
            warnings.showwarning = _warning_printer(name)
            from ._compile_cache import enable

            enable(disabled=args.no_compile_cache)
            return int(args._run(args) or 0)
    except KeyboardInterrupt:
        print(f"{name}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # the one handler
        if os.environ.get("LIONJAX_TRACEBACK"):
            raise
        print(f"{name}: error: {describe(e, args.command)}", file=sys.stderr)
        return EXIT_ERROR
    finally:
        cli_hints.reset(token)


def describe(e: BaseException, command: str = "") -> str:
    """The one-line message of an error raised by subcommand ``command`` (see :func:`main`):
    the library's name of the call that refused (``diagnose: …``) is dropped where it is the
    command's own; an error raised inside a user's candidate file (``--candidates``) names that
    file and line, not lionjax."""
    from .._errors import IdentificationError, InputError
    from ._common import CURRENT_FILE, one_line

    if isinstance(e, InputError | IdentificationError):
        text = one_line(str(e))
        return text[len(command) + 2 :] if command and text.startswith(f"{command}: ") else text
    user = _user_frame(e)
    if user is not None:
        path, line, func = user
        return one_line(
            f"the candidate file {path} failed (line {line}, in {func}): {type(e).__name__}: "
            f"{e}. The diagnosis calls a candidate's methods (basis, grid, implausible, …): fix "
            "it there (docs/effects.md, 'Rules for a good candidate')."
        )
    if isinstance(e, OSError):
        where = e.filename if e.filename is not None else CURRENT_FILE.get()
        why = e.strerror or str(e)
        return (
            f"{where}: {why}. Check the path and its permissions (and the free space when "
            "writing); an existing output file is left as it was."
            if where
            else f"{why}."
        )
    if isinstance(e, ImportError):
        return one_line(str(e))
    if isinstance(e, MemoryError):
        return (
            "out of memory; use a shorter record (or --decimate for the diagnosis) or a "
            "machine with more memory."
        )
    f = CURRENT_FILE.get()
    return one_line(
        f"internal error{f' on {f}' if f else ''}: {type(e).__name__}: {e}. This is a bug in "
        "lionjax, not in your input: please report it with the command line "
        "(LIONJAX_TRACEBACK=1 shows where it happened)."
    )


def _user_frame(e: BaseException) -> tuple[str, int, str] | None:
    """(file, line, function) of the deepest frame of ``e``'s traceback in a user's candidate
    file (a module :func:`lionjax.diagnosis.load_candidates` ran), or None."""
    from ..diagnosis._load import USER_MODULE

    tb, found = e.__traceback__, None
    while tb is not None:
        if str(tb.tb_frame.f_globals.get("__name__", "")).startswith(USER_MODULE):
            code = tb.tb_frame.f_code
            found = (code.co_filename, tb.tb_lineno, code.co_name)
        tb = tb.tb_next
    return found


def _warning_printer(name: str):
    """A ``warnings.showwarning`` that prints one line ``NAME: warning: [file: ]message``."""
    from ._common import CURRENT_FILE, one_line

    def show(message, category, filename, lineno, file=None, line=None):
        text = one_line(str(message))
        f = CURRENT_FILE.get()
        if f and f not in text:
            text = f"{f}: {text}"
        print(f"{name}: warning: {text}", file=sys.stderr)

    return show


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
