"""``facegeo reconstruct PHOTO -o OUT``: the whole pipeline, through
:func:`facegeo.jobs.reconstruct_into_folder` (fit.json, the asset folder, the scenes, preview.png)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from facegeo.commands.arguments import (
    Command,
    RegistryNames,
    add_batch_arguments,
    add_blendshape_arguments,
    add_fit_arguments,
    add_parts_argument,
    add_photo_arguments,
    add_regressor_arguments,
    option_defaults,
    parse_list,
    wants_batch,
)
from facegeo.commands.batch import run_batch

if TYPE_CHECKING:
    from facegeo.jobs import JobRecord, ReconstructOptions

__all__ = ["COMMANDS"]

#: The texture backends' names (``facegeo.texturing.registry.BACKENDS``).
BACKEND_NAMES = RegistryNames("facegeo.texturing.registry", "BACKENDS")


def _arguments(parser: argparse.ArgumentParser) -> None:
    from facegeo.asset import MAP_NAMES
    from facegeo.export.writers import FORMATS
    from facegeo.jobs import ReconstructOptions

    defaults = option_defaults(ReconstructOptions)
    add_photo_arguments(parser, many=True)
    add_fit_arguments(parser)
    add_regressor_arguments(parser)
    texture = parser.add_argument_group("texture and export")
    texture.add_argument("--backend", choices=BACKEND_NAMES, default=defaults["backend"], metavar="NAME",
                         help="texture backend, one of %(choices)s (default: weight-free, offline; diffusion: needs --weights "
                         "and the [diffusion] extra)")
    texture.add_argument("--weights", type=Path, default=None, metavar="DIR",
                         help="diffusion backend: folder with base/, loras/<task>/ and sr/ (see facegeo.texturing.diffusion.backend)")
    texture.add_argument("--size", type=int, default=defaults["size"], help="UV map size in texels (default %(default)d)")
    texture.add_argument("--upscale", type=int, choices=[1, 2, 4], default=defaults["upscale"], help="upscale the maps by this factor (Lanczos)")
    texture.add_argument("--subdiv", type=int, choices=[0, 1, 2, 3], default=defaults["subdiv"],
                         help="Loop subdivision levels of the exported mesh (displacement baked when > 0)")
    texture.add_argument("--maps", default=",".join(defaults["maps"]), metavar="NAME[,NAME]",
                         help=f"comma-separated maps to compute and export, among {', '.join(MAP_NAMES)} (default: all)")
    texture.add_argument("--format", default=",".join(defaults["formats"]), metavar="FMT[,FMT]",
                         help=f"comma-separated formats among {', '.join(FORMATS)} (default %(default)s)")
    add_parts_argument(texture)
    add_blendshape_arguments(texture)
    parser.add_argument("--no-preview", action="store_true", help="do not render preview.png")
    parser.add_argument("--one-person", action="store_true",
                        help="the photos are of one person: one identity fitted to all of them jointly and one texture fused from "
                        "all of them (each texel from the photos that see it best), into one folder (a photo of someone else "
                        "is named and left out)")
    add_batch_arguments(parser)


def _run(args: argparse.Namespace) -> int | None:
    from tqdm import tqdm

    from facegeo.asset import MAP_NAMES
    from facegeo.export.writers import FORMATS
    from facegeo.jobs import ReconstructOptions, reconstruct_into_folder

    maps = parse_list(args.maps, MAP_NAMES, "--maps")
    formats = parse_list(args.format, FORMATS, "--format")
    options = ReconstructOptions(model=args.model, landmarks=args.landmarks, focal=args.focal,
                         principal_point=tuple(args.principal_point) if args.principal_point else None, max_side=args.max_side,
                                 regressor=args.regressor, refine=args.refine, backend=args.backend, weights=args.weights,
                                 size=args.size, upscale=args.upscale, subdiv=args.subdiv, maps=tuple(maps),
                                 formats=tuple(formats), parts=args.parts, preview=not args.no_preview,
                                 blendshapes=args.blendshapes != "none", blendshape_names=args.blendshape_names)
    if args.one_person:
        return _run_one_person(args, options)
    if wants_batch(args):
        return run_batch(args, "reconstruct", options)
    bars: list[tqdm] = []  # made at the first stage: the pipeline (and torch) is imported by then, while the fit runs

    def progress(stage: str) -> None:
        if not bars:
            from facegeo.pipeline import STAGES

            bars.append(tqdm(total=len(STAGES) + 2, desc="reconstruct", unit="stage", disable=not sys.stderr.isatty(), leave=False))
        bars[0].set_postfix_str(stage)
        bars[0].update(1)

    record = reconstruct_into_folder(args.photo, args.output, options, progress=progress, fork=True)
    for bar in bars:
        bar.close()
    _report(record, f"reconstructed {args.photo}: landmark RMS {record.landmark_rms_px:.2f} px, maps {', '.join(record.maps)} "
                    f"at {record.map_size}², formats {', '.join(formats)}", args.output)
    return None


def _report(record: JobRecord, summary: str, output: Path) -> None:
    """Print the job's notes, ``summary``, its stage timings and where it wrote."""
    for note in record.notes:
        print(f"note: {note}")
    print(summary)
    print("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in record.timings.items()))
    print(f"wrote {output}")


def _run_one_person(args: argparse.Namespace, options: ReconstructOptions) -> None:
    """``reconstruct --one-person A B ... -o OUT``: the photos as given (no folders or manifests;
    ``-o`` checked with the other commands' by ``check_arguments``)."""
    from facegeo.commands.arguments import COMMAND_LINE
    from facegeo.errors import InputError
    from facegeo.jobs import reconstruct_one_person_into_folder

    photos = args.photo
    if len(photos) < 2 or any(Path(p).is_dir() for p in photos):
        raise InputError(COMMAND_LINE, "--one-person", "two or more photo files of the person", " ".join(map(str, photos)))
    record = reconstruct_one_person_into_folder(photos, args.output, options, fork=True)
    _report(record, f"reconstructed one person from {record.photo}: landmark RMS {record.landmark_rms_px:.2f} px "
                    f"(over the photos), maps {', '.join(record.maps)} at {record.map_size}²", args.output)


COMMANDS = (
    Command(
        "reconstruct",
        help="photo -> fit -> UV maps -> USD/glTF asset (the whole pipeline)",
        description="Fit the model, unwrap the photo into UV space, complete and de-light the texture, "
        "estimate PBR maps (albedo, normal, roughness, specular, displacement) and write fit.json, "
        "the maps (asset.json + PNGs, re-exportable with 'facegeo export'), the assets and preview.png "
        "(the photo beside the asset from the front, three-quarter and profile, textured and as clay).",
        arguments=_arguments,
        run=_run,
        output_folder=True,
    ),
)
