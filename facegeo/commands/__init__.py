"""The ``facegeo`` command line: the floor above the library (DESIGN.md, "Layers").

One module per subcommand or family, each declaring its :class:`~facegeo.commands.arguments.Command`
records in ``COMMANDS`` (:func:`~facegeo.commands.arguments.add_commands` adds them to a parser):

=============================  ==============================================================
module                         subcommands
=============================  ==============================================================
``commands.fit``               ``fit`` (:func:`facegeo.jobs.fit_into_folder`)
``commands.reconstruct``       ``reconstruct`` (:func:`facegeo.jobs.reconstruct_into_folder`)
``commands.unwrap``            ``unwrap``
``commands.export``            ``export``
``commands.animate``           ``animate``
``commands.realy``             ``realy``
``commands.regressor``         ``train-regressor``, ``make-synthetic-faces``
``commands.diffusion``         ``train-lora``, ``make-texture-pairs``
=============================  ==============================================================

``commands.arguments`` holds what they share: the fitting group (``--model/--landmarks/--focal/
--max-side``), choice lists read from the library's registries, and :func:`check_arguments`.
Building the parser imports nothing heavy (no torch, OpenCV or diffusers); a command imports
what it needs when it runs.

Every user-facing failure is a :class:`facegeo.errors.FacegeoError`: :func:`main` prints its one
message (file, field, what was expected) to stderr without a traceback and exits with status 2.
The options are checked by one path (:func:`~facegeo.commands.arguments.check_arguments`), and
the output location before any work is done. Outputs are staged in a hidden folder and moved
into place only when the run succeeds; SIGINT (Ctrl-C) and SIGTERM raise :class:`Interrupted`, so
the staged files are removed, one line is printed and the exit status is 128 + the signal number
(130, 143). A write that fails for want of room (ENOSPC, EFBIG) is one line and exit status 2.
"""

from __future__ import annotations

import argparse
import signal
import sys
from importlib import import_module
from typing import NoReturn

from facegeo import __version__
from facegeo.commands.arguments import COMMAND_LINE, add_commands, check_arguments
from facegeo.errors import FacegeoError

__all__ = ["main", "build_parser", "Interrupted", "COMMAND_MODULES", "COMMAND_OWNERS"]

#: The command modules, in the order ``facegeo --help`` lists their subcommands.
COMMAND_MODULES = ("fit", "reconstruct", "track", "unwrap", "export", "animate", "realy", "regressor", "diffusion")
#: The module of each subcommand (a test checks it against the modules' ``COMMANDS``), so that a
#: run of one subcommand builds its parser alone: adding the others' options took ~7 ms a run.
COMMAND_OWNERS = {"fit": "fit", "reconstruct": "reconstruct", "track": "track", "unwrap": "unwrap", "export": "export",
                  "animate": "animate", "realy": "realy", "train-regressor": "regressor", "make-synthetic-faces": "regressor",
                  "train-lora": "diffusion", "make-texture-pairs": "diffusion"}


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived; ``signum`` says which. A KeyboardInterrupt, so every
    ``StagedOutput`` on the way out removes its staged files."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _raise_interrupted(signum: int, frame: object) -> None:
    for s in (signal.SIGINT, signal.SIGTERM):  # a second signal must not cut the clean-up short
        signal.signal(s, signal.SIG_IGN)
    raise Interrupted(signum)


class _Parser(argparse.ArgumentParser):
    """argparse's parser with its usage errors on one line (it prints the usage above them)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"facegeo: error: {COMMAND_LINE}: {message} (see '{self.prog} --help')\n")


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The argument parser with all subcommands (those of :data:`COMMAND_MODULES`), or with the
    subcommand ``command`` alone (a key of :data:`COMMAND_OWNERS`): the parser of a command line
    that names it first, which parses it as the whole parser does."""
    parser = _Parser(prog="facegeo", description="One photo of a face in, a measured 3D face out.")
    parser.add_argument("--version", action="version", version=f"facegeo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMAND_MODULES if command is None else (COMMAND_OWNERS[command],):
        add_commands(sub, [c for c in import_module(f"facegeo.commands.{name}").COMMANDS if command in (None, c.name)])
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``facegeo`` console command; returns the exit status: 0, 2 for bad
    input or a failed write (one line on stderr), 128 + signal number after SIGINT/SIGTERM; a
    batch (several photos) also 3 when some photos failed (:data:`facegeo.batch.EXIT_STATUS`)."""
    import threading

    on_main_thread = threading.current_thread() is threading.main_thread()  # only there can signals be caught
    previous = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGINT, signal.SIGTERM)} if on_main_thread else {}
    status: int | None = None
    try:
        words = sys.argv[1:] if argv is None else argv
        parser = build_parser(words[0] if words and words[0] in COMMAND_OWNERS else None)
        args = parser.parse_args(words)
        check_arguments(args)
        status = args.run(args)
    except FacegeoError as exc:
        print(f"facegeo: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # a fault no facegeo check turned into a FacegeoError: still one line
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"facegeo: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
        print(f"facegeo: interrupted ({signal.Signals(signum).name}); no output written", file=sys.stderr)
        return 128 + int(signum)
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return int(status or 0)
