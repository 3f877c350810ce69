"""``facegeo fit PHOTO -o OUT``: the geometry alone, through :func:`facegeo.jobs.fit_into_folder`
(``fit.json``, ``mesh.obj``, ``overlay.png``)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from facegeo.commands.arguments import (Command, add_batch_arguments, add_fit_arguments, add_photo_arguments,
                                       add_regressor_arguments, wants_batch)
from facegeo.commands.batch import run_batch

if TYPE_CHECKING:
    from facegeo.jobs import FitOptions

__all__ = ["COMMANDS"]


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_photo_arguments(parser, many=True)
    add_fit_arguments(parser)
    parser.add_argument("--no-photometric", action="store_true", help="skip the albedo and lighting stage")
    parser.add_argument("--one-person", action="store_true",
                        help="the photos are of one person: one identity fitted to all of them jointly, a pose, expression and camera "
                        "per photo, into one fit.json (a photo of someone else is named and left out)")
    add_regressor_arguments(parser)
    add_batch_arguments(parser)


def _run(args: argparse.Namespace) -> int | None:
    from facegeo.jobs import FitOptions, fit_into_folder

    options = FitOptions(model=args.model, landmarks=args.landmarks, focal=args.focal,
                         principal_point=tuple(args.principal_point) if args.principal_point else None, max_side=args.max_side,
                         photometric=not args.no_photometric, regressor=args.regressor, refine=args.refine)
    if args.one_person:
        return _run_one_person(args, options)
    if wants_batch(args):
        return run_batch(args, "fit", options)
    record = fit_into_folder(args.photo, args.output, options)
    for note in record.notes:
        print(f"note: {note}")
    print(
        f"fitted {args.photo}: landmark RMS {record.landmark_rms_px:.2f} px = "
        f"{record.landmark_rms_percent_iod:.2f} % of the inter-ocular distance"
    )
    print("timings: " + ", ".join(f"{k} {v:.3f} s" for k, v in record.timings.items()))
    print(f"wrote {args.output}/" + ", ".join(record.files))
    return None


def _run_one_person(args: argparse.Namespace, options: FitOptions) -> None:
    """``fit --one-person A B ... -o OUT``: the photos as given (no folders or manifests; ``-o``
    checked with the other commands' by ``check_arguments``)."""
    from facegeo.commands.arguments import COMMAND_LINE
    from facegeo.errors import InputError
    from facegeo.jobs import fit_one_person_into_folder

    photos = args.photo
    if len(photos) < 2 or any(Path(p).is_dir() for p in photos):
        raise InputError(COMMAND_LINE, "--one-person", "two or more photo files of the person", " ".join(map(str, photos)))
    record = fit_one_person_into_folder(photos, args.output, options)
    for note in record.notes:
        print(f"note: {note}")
    print(f"fitted one person to {len(photos)} photos: landmark RMS {record.landmark_rms_px:.2f} px = "
          f"{record.landmark_rms_percent_iod:.2f} % of the inter-ocular distance (over the photos)")
    print(f"wrote {args.output}/" + ", ".join(record.files))


COMMANDS = (
    Command(
        "fit",
        help="fit the morphable model to a photo (fit.json, mesh.obj, overlay.png)",
        description="Detect 88 landmarks, fit pose, identity, expression, albedo and SH lighting, "
        "and write fit.json (parameters, camera, per-point landmark errors, timings), mesh.obj "
        "(posed mesh in camera space, mm, with UVs) and overlay.png.",
        arguments=_arguments,
        run=_run,
        output_folder=True,
    ),
)
