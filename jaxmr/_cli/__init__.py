"""The `jaxmr` command line: `jaxmr demo`, `fit`, `predict`, `report`, `convert`,
`design` and `export`.

A module per command (`demo.py`, `fit.py`, ...), each with `add_parser(subparsers)`,
which registers its arguments, and `run(args) -> int`, which runs it; `files.py` reads
the inputs and writes every output by one rule (never over an input, an existing file
only with `--force`, each file whole or not at all); `errors.py` holds `CLIError`.
`main` (here) assembles the parser, sets up the persistent compilation cache
(`cache.py`), dispatches, collects the warnings, and turns a
`CLIError` into a message on stderr and exit status 1 (argparse's usage errors exit
with 2), and Ctrl-C into exit status 130.

The command line is a user of jaxmr's public API (`jaxmr` and its public submodules:
`jaxmr.data`, `jaxmr.templates`, `jaxmr.scores`, `jaxmr.metrics`, `jaxmr.devices`, `jaxmr.plot`): tests/test_cli.py checks that no module here imports
a private jaxmr module.
"""

import argparse
import os
import signal
import sys
import threading
import warnings
from collections.abc import Sequence

# Light imports only: `jaxmr --help` and a usage error must not wait seconds for JAX.
# `jaxmr/__init__.py` imports its public names on first use, `jaxmr.plot` imports
# matplotlib when it draws, and JAX with jaxmr's models and identification (and
# `jaxmr.data`, which builds on them) are imported by the commands that use them.
import jaxmr

from . import cache, convert, demo, design, export, fit, predict, report
from .errors import INTERRUPTED, CLIError

__all__ = ["CLIError", "main"]

# The commands, in the order of `jaxmr --help`.
COMMANDS = (demo, fit, predict, report, convert, design, export)


def main(argv: Sequence[str | os.PathLike] | None = None) -> int:
    """Run the `jaxmr` command line with `argv` (default: `sys.argv[1:]`).

    **Returns:** the exit status: 0 on success, 1 on an error reported on stderr,
    130 when interrupted by Ctrl-C (argparse exits with 2 on a usage error). With
    `argv=None` (the `jaxmr` program) Ctrl-C is ignored once the command is done.
    """
    parser = _parser()
    args = parser.parse_args(None if argv is None else [os.fspath(a) for a in argv])
    try:
        # Only now, with a command to run: JAX takes seconds to import. jaxmr never
        # changes JAX's configuration on import; the command line is an application
        # and wants the accuracy of double precision (Adaptive's rtol 1e-8).
        # Simulation loops compiled as one kernel each; for `fit`, every core an XLA
        # device, over which it splits its lanes. Only as the program: `main()`
        # called from Python, after JAX, leaves its caller's settings alone.
        program = "jax" not in sys.modules
        if program:
            # Imports JAX but starts no backend: the XLA flags still apply.
            from jaxmr.devices import configure_cpu

            configure_cpu(devices=None if args.command == "fit" else 1)
        import jax

        jax.config.update("jax_enable_x64", True)
        # The persistent compilation cache (`cache.py`): by default for the program,
        # where `jaxmr fit` then says it lives.
        args.compilation_cache_folder = cache.configure(args.compilation_cache, program)
        # The fit's traced programs beside the compiled ones, for this command only:
        # a caller's later library calls write nothing.
        from jaxmr.devices import traced_programs_in

        programs = cache.programs(args.compilation_cache_folder)
        with _Warnings(args.command) as args.warnings, traced_programs_in(programs):
            return args.run(args)
    except CLIError as e:
        print(f"jaxmr {args.command}: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # Every file is written whole (through a rename) or not at all.
        print(f"\njaxmr {args.command}: interrupted", file=sys.stderr)
        return INTERRUPTED
    finally:
        if argv is None and threading.current_thread() is threading.main_thread():
            # The program ends here: a Ctrl-C in JAX's clean-up at exit would only
            # print a traceback.
            signal.signal(signal.SIGINT, signal.SIG_IGN)


class _Warnings(list):
    """The `UserWarning`s raised while a command runs (a file's implausible units,
    float32, ...), as a context manager: each distinct message is printed once on
    stderr, `jaxmr <command>: warning: ...` (the file and line of the code that warned
    mean nothing to a user of the command line), and kept in this list for the
    command's report (`jaxmr fit` writes them into the JSON). Other warnings are left
    to Python's filters."""

    def __init__(self, command: str):
        super().__init__()
        self.command = command
        self._context = warnings.catch_warnings()

    def __enter__(self):
        self._context.__enter__()  # restores the filters and `showwarning` on exit
        warnings.simplefilter("always", UserWarning)
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not issubclass(category, UserWarning):
                return shown(message, category, filename, lineno, file, line)
            text = str(message)
            if text not in self:
                self.append(text)
                print(f"jaxmr {self.command}: warning: {text}", file=sys.stderr)

        warnings.showwarning = show
        return self

    def __exit__(self, *exc_info):
        return self._context.__exit__(*exc_info)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxmr",
        description="Differentiable physics of magnetorheological dampers and brakes.",
    )
    parser.add_argument(
        "--version", action="version", version=f"%(prog)s {jaxmr.__version__}"
    )
    subparsers = parser.add_subparsers(
        title="commands", dest="command", metavar="COMMAND", required=True
    )
    for command in COMMANDS:
        command.add_parser(subparsers)
    for command_parser in subparsers.choices.values():
        cache.add_argument(command_parser)
    return parser
