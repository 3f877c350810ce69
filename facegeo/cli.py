"""The ``facegeo`` command line.

Every user-facing failure is a :class:`facegeo.errors.FacegeoError`: the command prints its one
message (file, field, what was expected) to stderr without a traceback and exits with status 2.
The options are checked by one path (:func:`check_arguments`), and the output location before
any work is done. Outputs are staged in a hidden folder and moved into place only when the run
succeeds; SIGINT (Ctrl-C) and SIGTERM raise :class:`Interrupted`, so the staged files are
removed, one line is printed and the exit status is 128 + the signal number (130, 143). A write
that fails for want of room (ENOSPC, EFBIG) is one line and exit status 2 as well.
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
from pathlib import Path
from typing import Iterable, NoReturn

from facegeo import __version__
from facegeo.batch import add_batch_arguments, run_batch, wants_batch
from facegeo.errors import FacegeoError, InputError
from facegeo.regressor.cli import add_regressor_arguments
from facegeo.regressor.cli import register as register_regressor

__all__ = ["main", "build_parser", "add_fit_arguments", "add_parts_argument", "check_arguments", "parse_list", "Interrupted",
           "COMMAND_LINE"]

#: The command line as the ``source`` of an :class:`InputError` about an option.
COMMAND_LINE = "<command line>"


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
    ``--max-side`` (≥ MIN_SIDE px), ``--focal`` (finite, > 0 px), and, for the commands that write
    an output folder (``output_folder`` set by their parser), the ``-o`` location
    (:func:`facegeo.staged_output.check_output_location`: name lengths, parents, writability,
    an existing folder must be empty or an earlier facegeo output; and it must not hold an input
    file such as the photo, since it is replaced as a whole).

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
    if getattr(args, "refine", False) and getattr(args, "regressor", None) is None:
        raise InputError(COMMAND_LINE, "--refine", "--regressor CKPT with it", "no --regressor")
    if getattr(args, "weights", None) is not None and getattr(args, "backend", "diffusion") != "diffusion":
        raise InputError(COMMAND_LINE, "--weights", "--backend diffusion", f"--backend {args.backend}")
    if isinstance(getattr(args, "photo", None), list) and not wants_batch(args):
        args.photo = args.photo[0]  # one photo, no batch option: the single-photo command
    if getattr(args, "output_folder", False) and not wants_batch(args):  # a batch checks its OUT itself
        check_output_location(args.output, folder=True, replace=True)
        out = Path(args.output).resolve()
        for name, value in vars(args).items():  # an existing OUT is replaced: it must not hold an input
            if name != "output" and isinstance(value, Path) and value.exists() and out in value.resolve().parents:
                raise InputError(COMMAND_LINE, "-o", "an output folder that does not hold the inputs (it is replaced as a whole)",
                                 f"{args.output}, which holds {value}")


class _Parser(argparse.ArgumentParser):
    """argparse's parser with its usage errors on one line (it prints the usage above them)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"facegeo: error: {COMMAND_LINE}: {message} (see '{self.prog} --help')\n")


def add_fit_arguments(parser: argparse.ArgumentParser, many: bool = False) -> None:
    """The photo, output folder and fitting options shared by ``fit`` and ``unwrap``; with
    ``many``, ``photo`` takes several (a batch: :mod:`facegeo.batch`)."""
    parser.add_argument("photo", type=Path, nargs="+" if many else None,
                        help="the photo (PNG, JPEG, ...); EXIF orientation is honoured"
                        + ("; or several, folders, glob patterns, manifests (see batch)" if many else ""))
    parser.add_argument("-o", "--output", type=Path, required=True, help="output folder (created; an existing one must be empty or an earlier facegeo output, and is replaced)")
    parser.add_argument("--model", type=Path, default=None, help="model file (.npz, HIFI3D++ .mat, AI-NExT .mat); default: $FACEGEO_MODEL or the bundled ICT-FaceKit model")
    parser.add_argument("--landmarks", choices=["hybrid", "dlib", "mediapipe"], default="hybrid", help="landmark detector (default: hybrid = dlib 68 + MediaPipe 20 lip points; mediapipe is licence-clean for commercial use)")
    parser.add_argument("--focal", type=float, default=None, help="focal length in pixels of the (possibly downscaled) photo; default: 40° field of view on the long side")
    parser.add_argument("--max-side", type=int, default=2048, help="downscale photos whose longer side exceeds this (pixels)")


def add_parts_argument(parser: argparse.ArgumentParser) -> None:
    """``--parts face|head|full``: what the written scenes hold (``reconstruct`` and ``export``)."""
    from facegeo.asset import PART_CHOICES

    parser.add_argument("--parts", choices=PART_CHOICES, default="full",
                        help="what the USD/glTF scenes hold: face = the face region of the skin, head = all the skin, "
                        "full = the head with eyes and mouth interior (default; the model's parts, if it has any)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with all subcommands."""
    parser = _Parser(prog="facegeo", description="One photo of a face in, a measured 3D face out.")
    parser.add_argument("--version", action="version", version=f"facegeo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    fit = sub.add_parser(
        "fit",
        help="fit the morphable model to a photo (fit.json, mesh.obj, overlay.png)",
        description="Detect 88 landmarks, fit pose, identity, expression, albedo and SH lighting, "
        "and write fit.json (parameters, camera, per-point landmark errors, timings), mesh.obj "
        "(posed mesh in camera space, mm, with UVs) and overlay.png.",
    )
    add_fit_arguments(fit, many=True)
    add_batch_arguments(fit)
    fit.add_argument("--no-photometric", action="store_true", help="skip the albedo and lighting stage")
    add_regressor_arguments(fit)
    fit.set_defaults(run=_run_fit, output_folder=True)

    rec = sub.add_parser(
        "reconstruct",
        help="photo -> fit -> UV maps -> USD/glTF asset (the whole pipeline)",
        description="Fit the model, unwrap the photo into UV space, complete and de-light the texture, "
        "estimate PBR maps (albedo, normal, roughness, specular, displacement) and write fit.json, "
        "the maps (asset.json + PNGs, re-exportable with 'facegeo export'), the assets and preview.png "
        "(the photo beside the asset from the front, three-quarter and profile, textured and as clay).",
    )
    rec.add_argument("photo", type=Path, nargs="+", help="the photo; or several, folders, glob patterns, manifests (see batch)")
    rec.add_argument("-o", "--output", type=Path, required=True, help="output folder (created; an existing one must be empty or an earlier facegeo output, and is replaced)")
    rec.add_argument("--backend", choices=["default", "diffusion"], default="default", help="texture backend (default: weight-free, offline; diffusion: needs --weights and the [diffusion] extra)")
    rec.add_argument("--weights", type=Path, default=None, help="diffusion backend: folder with base/, loras/<task>/ and sr/ (see facegeo.texturing.diffusion.backend)")
    rec.add_argument("--size", type=int, default=1024, help="UV map size in texels (default 1024)")
    rec.add_argument("--upscale", type=int, choices=[1, 2, 4], default=1, help="upscale the maps by this factor (Lanczos)")
    rec.add_argument("--subdiv", type=int, choices=[0, 1, 2, 3], default=0, help="Loop subdivision levels of the exported mesh (displacement baked)")
    rec.add_argument("--maps", default="albedo,normal,roughness,specular,displacement", help="comma-separated maps to compute and export")
    rec.add_argument("--format", default="usdz,glb", help="comma-separated formats among usdz, usdc, usda, glb (default usdz,glb)")
    rec.add_argument("--model", type=Path, default=None, help="model file (see 'facegeo fit --help')")
    rec.add_argument("--landmarks", choices=["hybrid", "dlib", "mediapipe"], default="hybrid", help="landmark detector")
    rec.add_argument("--max-side", type=int, default=2048, help="downscale photos whose longer side exceeds this (pixels)")
    rec.add_argument("--no-preview", action="store_true", help="do not render preview.png")
    add_parts_argument(rec)
    add_regressor_arguments(rec)
    add_batch_arguments(rec)
    rec.set_defaults(run=_run_reconstruct, output_folder=True)

    from facegeo.eval.realy_cli import register as register_realy
    from facegeo.export.cli import register as register_export
    from facegeo.texturing.diffusion.cli import register as register_diffusion
    from facegeo.uv.cli import register as register_unwrap

    register_unwrap(sub)
    register_export(sub)
    register_realy(sub)
    register_regressor(sub)
    register_diffusion(sub)
    return parser


def _run_fit(args: argparse.Namespace) -> int | None:
    from facegeo.jobs import FitOptions, fit_into_folder

    options = FitOptions(model=args.model, landmarks=args.landmarks, focal=args.focal, max_side=args.max_side,
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


def _run_reconstruct(args: argparse.Namespace) -> int | None:
    from tqdm import tqdm

    from facegeo.asset import MAP_NAMES
    from facegeo.export.writers import FORMATS
    from facegeo.jobs import ReconstructOptions, reconstruct_into_folder
    from facegeo.pipeline import STAGES

    maps = parse_list(args.maps, MAP_NAMES, "--maps")
    formats = parse_list(args.format, FORMATS, "--format")
    options = ReconstructOptions(model=args.model, landmarks=args.landmarks, max_side=args.max_side,
                                 regressor=args.regressor, refine=args.refine, backend=args.backend, weights=args.weights,
                                 size=args.size, upscale=args.upscale, subdiv=args.subdiv, maps=tuple(maps),
                                 formats=tuple(formats), parts=args.parts, preview=not args.no_preview)
    if wants_batch(args):
        return run_batch(args, "reconstruct", options)
    bar = tqdm(total=len(STAGES) + 2, desc="reconstruct", unit="stage", disable=not sys.stderr.isatty(), leave=False)

    def progress(stage: str) -> None:
        bar.set_postfix_str(stage)
        bar.update(1)

    record = reconstruct_into_folder(args.photo, args.output, options, progress=progress)
    bar.close()
    for note in record.notes:
        print(f"note: {note}")
    print(f"reconstructed {args.photo}: landmark RMS {record.landmark_rms_px:.2f} px, maps {', '.join(record.maps)} "
          f"at {record.map_size}², formats {', '.join(formats)}")
    print("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in record.timings.items()))
    print(f"wrote {args.output}")
    return None


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``facegeo`` console command; returns the exit status: 0, 2 for bad
    input or a failed write (one line on stderr), 128 + signal number after SIGINT/SIGTERM; a
    batch (several photos) also 3 when some photos failed (:data:`facegeo.batch.EXIT_STATUS`)."""
    import threading

    on_main_thread = threading.current_thread() is threading.main_thread()  # only there can signals be caught
    previous = {s: signal.signal(s, _raise_interrupted) for s in (signal.SIGINT, signal.SIGTERM)} if on_main_thread else {}
    status: int | None = None
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
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


if __name__ == "__main__":
    sys.exit(main())
