"""What the subcommands share: the :class:`Command` record each command module declares, the
argument groups (photo and output folder, the fitting options, the regressor options, the parts),
choice lists read from the library's registries, and the one validation path of the options
(:func:`check_arguments`), run before any work.

Every error about an option is an :class:`facegeo.errors.InputError` whose source is
:data:`COMMAND_LINE`; ``facegeo.commands.main`` prints it as one line and exits with status 2.
"""

from __future__ import annotations

import argparse
import math
import os
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, fields
from importlib import import_module
from pathlib import Path
from typing import Any

from facegeo.batch import GLOB_CHARS, MANIFEST_SUFFIXES, SCHEDULER_ENV
from facegeo.errors import InputError

__all__ = ["Command", "add_commands", "RegistryNames", "COMMAND_LINE", "DETECTOR_NAMES", "parse_list", "check_arguments", "option_defaults",
           "add_photo_arguments", "add_fit_arguments", "add_model_argument", "add_regressor_arguments", "add_parts_argument",
           "add_seed_argument", "add_device_argument", "add_batch_arguments", "wants_batch", "add_blendshape_arguments",
           "BLENDSHAPE_NAMINGS"]

#: The command line as the ``source`` of an :class:`InputError` about an option.
COMMAND_LINE = "<command line>"


@dataclass(frozen=True)
class Command:
    """One subcommand: its name, one-line ``help`` (the ``facegeo --help`` list), ``description``
    (its own ``--help``), ``arguments`` (adds its options to its parser) and ``run`` (does the work
    for the parsed namespace; raises :class:`facegeo.errors.FacegeoError`). ``output_folder``: its
    ``-o`` is a run's output folder (its earlier run's files are replaced, other files kept),
    checked by :func:`check_arguments` before any work."""

    name: str
    help: str
    description: str
    arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int | None]
    output_folder: bool = False


def add_commands(subparsers: argparse._SubParsersAction, commands: Iterable[Command]) -> list[argparse.ArgumentParser]:
    """Add ``commands`` to ``facegeo``'s sub-parsers; returns their parsers (in order)."""
    parsers = []
    for command in commands:
        parser = subparsers.add_parser(command.name, help=command.help, description=command.description)
        command.arguments(parser)
        parser.set_defaults(run=command.run, output_folder=command.output_folder)
        parsers.append(parser)
    return parsers


class RegistryNames(Sequence[str]):
    """The names of a registry (a dict or tuple attribute of a module), read when argparse first
    needs them (to check a value or print help), so that building the parser imports nothing
    heavy: the detectors' registry lives beside the detectors, which import OpenCV and torch.
    Give the option an explicit ``metavar`` (argparse would otherwise list the names at once)
    and ``%(choices)s`` in its help. ``extra``: names accepted besides the registry's, first."""

    def __init__(self, module: str, attribute: str, extra: tuple[str, ...] = ()):
        self.module, self.attribute, self.extra = module, attribute, extra

    def _names(self) -> tuple[str, ...]:
        return (*self.extra, *getattr(import_module(self.module), self.attribute))

    def __getitem__(self, index):  # type: ignore[override]
        return self._names()[index]

    def __len__(self) -> int:
        return len(self._names())

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    def __contains__(self, name: object) -> bool:
        return name in self._names()


#: The landmark detectors' names (``facegeo.landmarks.DETECTORS``).
DETECTOR_NAMES = RegistryNames("facegeo.landmarks.detectors", "DETECTORS")


def parse_list(text: str, allowed: Iterable[str], option: str) -> list[str]:
    """The comma-separated names of ``option`` (lower-cased, a leading dot dropped), each among
    ``allowed``; raises InputError for an unknown name or an empty list."""
    allowed = tuple(allowed)
    names = [n.strip().lower().lstrip(".") for n in text.split(",") if n.strip()]
    if not names:
        raise InputError(COMMAND_LINE, option, f"one or more of {', '.join(allowed)}, comma-separated", repr(text))
    for name in names:
        if name not in allowed:
            raise InputError(COMMAND_LINE, option, f"names among {', '.join(allowed)}", repr(name))
    return names


def check_arguments(args: argparse.Namespace) -> None:
    """The one validation path of the options the subcommands share, run before any work:
    ``--max-side`` (≥ MIN_SIDE px), ``--focal`` (finite, > 0 px), ``--refine`` only with
    ``--regressor``, ``--weights`` only with ``--backend diffusion``, and, for the commands that
    write an output folder (:attr:`Command.output_folder`), the ``-o`` location
    (:func:`facegeo.staged_output.check_output_location`: name lengths, parents, writability,
    an existing folder must be empty or an earlier facegeo output; and it must not hold an input
    file such as the photo, whose name a facegeo file could have).

    Raises:
        InputError: naming the option and what was expected.
    """
    from facegeo.photo import MIN_SIDE
    from facegeo.staged_output import check_output_location

    max_side = getattr(args, "max_side", None)
    if max_side is not None and max_side < MIN_SIDE:
        raise InputError(COMMAND_LINE, "--max-side", f"an integer of at least {MIN_SIDE} (pixels; smaller photos hold no findable face)", str(max_side))
    focal = getattr(args, "focal", None)
    if focal is not None and not (math.isfinite(focal) and focal > 0):
        raise InputError(COMMAND_LINE, "--focal", "a finite focal length > 0 in pixels", str(focal))
    principal_point = getattr(args, "principal_point", None)
    if principal_point is not None and not all(math.isfinite(v) for v in principal_point):
        raise InputError(COMMAND_LINE, "--principal-point", "two finite pixel coordinates CX CY", " ".join(map(str, principal_point)))
    if getattr(args, "refine", False) and getattr(args, "regressor", None) is None:
        raise InputError(COMMAND_LINE, "--refine", "--regressor CKPT with it", "no --regressor")
    if getattr(args, "weights", None) is not None and getattr(args, "backend", "diffusion") != "diffusion":
        raise InputError(COMMAND_LINE, "--weights", "--backend diffusion", f"--backend {args.backend}")
    one_person = getattr(args, "one_person", False)  # several photos into one folder, not a batch
    if isinstance(getattr(args, "photo", None), list) and not wants_batch(args) and not one_person:
        args.photo = args.photo[0]  # one photo, no batch option: the single-photo command
    if getattr(args, "output_folder", False) and (one_person or not wants_batch(args)):  # a batch checks its OUT itself
        check_output_location(args.output, folder=True, replace=True)
        out = Path(args.output).resolve()
        for name, value in vars(args).items():  # facegeo replaces files in OUT: it must not hold an input
            for path in value if isinstance(value, list) else [value]:
                if name != "output" and isinstance(path, Path) and path.exists() and out in path.resolve().parents:
                    raise InputError(COMMAND_LINE, "-o", "an output folder that does not hold the inputs (facegeo replaces files in it)",
                                     f"{args.output}, which holds {path}")


def add_photo_arguments(parser: argparse.ArgumentParser, many: bool = False) -> None:
    """The photo and the output folder (``PHOTO -o OUT``) of the commands that fit a photo; with
    ``many``, ``photo`` takes several (a batch: :mod:`facegeo.batch`)."""
    parser.add_argument("photo", type=Path, nargs="+" if many else None,
                        help="the photo (PNG, JPEG, ...); EXIF orientation is honoured"
                        + ("; or several, folders, glob patterns, manifests (see batch)" if many else ""))
    parser.add_argument("-o", "--output", type=Path, required=True,
                        help="output folder (created; an existing one must be empty or an earlier facegeo output: the earlier "
                        "run's files are replaced, your own files in it are kept)")


def add_model_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--model PATH``: the morphable model file."""
    parser.add_argument("--model", type=Path, default=None,
                        help="model file (.npz, HIFI3D++ .mat, AI-NExT .mat); default: $FACEGEO_MODEL or the bundled ICT-FaceKit model")


def option_defaults(options: type) -> dict[str, Any]:
    """The default of each field of an options dataclass (e.g. :class:`facegeo.jobs.FitOptions`),
    so that the command line's defaults are the library's."""
    return {f.name: f.default for f in fields(options)}


def add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """The fitting options every subcommand that fits a photo takes, as one group:
    ``--model``, ``--landmarks`` (the detectors' registry), ``--focal``, ``--max-side``
    (fields of :class:`facegeo.jobs.FitOptions`, whose defaults they take)."""
    from facegeo.jobs import FitOptions

    defaults = option_defaults(FitOptions)
    group = parser.add_argument_group("fitting")
    add_model_argument(group)
    group.add_argument("--landmarks", choices=DETECTOR_NAMES, default=defaults["landmarks"], metavar="NAME",
                       help="landmark detector, one of %(choices)s (default: hybrid = dlib 68 + MediaPipe 20 lip points; "
                       "mediapipe is licence-clean for commercial use)")
    group.add_argument("--focal", type=float, default=None, metavar="PX",
                       help="focal length in pixels of the (possibly downscaled) photo; default: estimated from the face "
                       "(the face is assumed about 1 m from the camera)")
    group.add_argument("--principal-point", type=float, nargs=2, default=None, metavar=("CX", "CY"),
                       help="principal point in pixels of the (possibly downscaled) photo, e.g. of a cropped photo; default: the centre")
    group.add_argument("--max-side", type=int, default=defaults["max_side"], metavar="N",
                       help="downscale photos whose longer side exceeds this (pixels; default %(default)d)")


def add_regressor_arguments(parser: argparse.ArgumentParser) -> None:
    """``--regressor CKPT`` and ``--refine`` (``fit`` and ``reconstruct``; the regressor is the
    second :class:`facegeo.fitting.Fitter`)."""
    parser.add_argument("--regressor", type=Path, default=None, metavar="CKPT",
                        help="use a trained regressor checkpoint (facegeo train-regressor) instead of the analysis-by-synthesis fit")
    parser.add_argument("--refine", action="store_true",
                        help="with --regressor: run the analysis-by-synthesis fit started from the prediction")


def add_parts_argument(parser: argparse.ArgumentParser) -> None:
    """``--parts face|head|full``: what the written scenes hold (``reconstruct`` and ``export``)."""
    from facegeo.asset import PART_CHOICES

    parser.add_argument("--parts", choices=PART_CHOICES, default="full",
                        help="what the USD/glTF scenes hold: face = the face region of the skin, head = all the skin, "
                        "full = the head with eyes and mouth interior (default; the model's parts, if it has any)")


#: The blendshape namings (``facegeo.arkit.BLENDSHAPE_NAMINGS``).
BLENDSHAPE_NAMINGS = RegistryNames("facegeo.arkit", "BLENDSHAPE_NAMINGS")


def add_blendshape_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, choose: bool = True) -> None:
    """``--blendshapes all|none`` (with ``choose``) and ``--blendshape-names arkit|ict``: whether
    and how the scenes carry the expression blendshapes (``reconstruct``, ``export``, ``animate``)."""
    if choose:
        parser.add_argument("--blendshapes", choices=("all", "none"), default="all",
                            help="all (default): the expression blendshapes as glTF morph targets and UsdSkel blend shapes, "
                            "set to the photo's expression (animatable); none: a static asset (smaller files)")
    parser.add_argument("--blendshape-names", choices=BLENDSHAPE_NAMINGS, default="arkit", metavar="NAMES",
                        help="the blendshapes' names, one of %(choices)s (default arkit: jawOpen, eyeBlinkLeft, ... as Live Link "
                        "Face, Unreal and three.js name them; ict: the model's own, eyeBlink_L, ...)")


def add_seed_argument(parser: argparse.ArgumentParser, what: str = "random seed") -> None:
    """``--seed S`` (default 0)."""
    parser.add_argument("--seed", type=int, default=0, help=f"{what} (default %(default)d)")


def add_device_argument(parser: argparse.ArgumentParser) -> None:
    """``--device`` for the training commands."""
    parser.add_argument("--device", default=None, help="torch device, e.g. cuda or cpu (default: cuda when available)")


def add_batch_arguments(parser: argparse.ArgumentParser) -> None:
    """The batch options of ``fit`` and ``reconstruct`` (their ``photo`` argument takes several)."""
    g = parser.add_argument_group(
        "batch", "With several photos, a folder, a glob pattern or a manifest (.txt/.lst, one path per line), or "
        "any option below, -o OUT is a batch folder: OUT/<photo name>/ per photo, items.csv, summary.csv, "
        "failures.csv. Exit status: 0 all done, 3 some photos failed, 2 bad invocation, 130 interrupted.")
    g.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes of the embedded Dask cluster, one thread each (default: the CPU cores)")
    g.add_argument("--scheduler", default=os.environ.get(SCHEDULER_ENV) or None, metavar="ADDRESS",
                   help=f"run on an existing Dask cluster (default ${SCHEDULER_ENV}); OUT must be on a file "
                   "system the workers share, unless --send-files")
    g.add_argument("--send-files", action="store_true",
                   help="workers send each item's files back and this process writes them (no shared file system)")
    g.add_argument("--resume", action="store_true",
                   help="complete the earlier batch in OUT: skip photos whose folder is complete (without it an "
                   "earlier batch output is refused)")
    g.add_argument("--retries", type=int, default=2, metavar="N",
                   help="re-runs of a photo after an unexpected error or a worker death (default 2; a bad photo "
                   "fails at once)")


def wants_batch(args: argparse.Namespace) -> bool:
    """Whether ``args`` (of ``fit`` / ``reconstruct``, ``photo`` a list) ask for a batch: several
    photos, a folder, a manifest, a glob pattern, or a batch option. One photo path without
    batch options is the single-photo command, exactly as before."""
    photos = getattr(args, "photo", None)
    if not isinstance(photos, list):
        return False
    if len(photos) != 1 or args.workers is not None or args.resume or args.send_files:
        return True
    if args.scheduler and args.scheduler != os.environ.get(SCHEDULER_ENV):
        return True  # given on the command line (the environment alone does not make one photo a batch)
    path = Path(photos[0])
    return path.is_dir() or (path.suffix.lower() in MANIFEST_SUFFIXES and path.is_file()) or (
        not path.exists() and bool(GLOB_CHARS & set(str(path))))
