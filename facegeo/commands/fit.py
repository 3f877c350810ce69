"""``facegeo fit PHOTO -o OUT``: the geometry alone, through :func:`facegeo.jobs.fit_into_folder`
(``fit.json``, ``mesh.obj``, ``overlay.png``)."""

from __future__ import annotations

import argparse

from facegeo.commands.arguments import (Command, add_batch_arguments, add_fit_arguments, add_photo_arguments,
                                       add_regressor_arguments, wants_batch)
from facegeo.commands.batch import run_batch

__all__ = ["COMMANDS"]


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_photo_arguments(parser, many=True)
    add_fit_arguments(parser)
    parser.add_argument("--no-photometric", action="store_true", help="skip the albedo and lighting stage")
    add_regressor_arguments(parser)
    add_batch_arguments(parser)


def _run(args: argparse.Namespace) -> int | None:
    from facegeo.jobs import FitOptions, fit_into_folder

    options = FitOptions(model=args.model, landmarks=args.landmarks, focal=args.focal,
                         principal_point=tuple(args.principal_point) if args.principal_point else None, max_side=args.max_side,
                         photometric=not args.no_photometric, regressor=args.regressor, refine=args.refine)
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
