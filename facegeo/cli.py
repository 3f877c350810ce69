"""The ``facegeo`` command line.

Every user-facing failure is a :class:`facegeo.errors.FacegeoError`: the command prints its one
message (file, field, what was expected) to stderr without a traceback and exits with status 2.
Outputs are staged in a hidden folder and moved into place only when the run succeeds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path


from facegeo import __version__
from facegeo.errors import FacegeoError

__all__ = ["main", "build_parser", "add_fit_arguments"]


def add_fit_arguments(parser: argparse.ArgumentParser) -> None:
    """The photo, output folder and fitting options shared by ``fit`` and ``unwrap``."""
    parser.add_argument("photo", type=Path, help="the photo (PNG, JPEG, ...); EXIF orientation is honoured")
    parser.add_argument("-o", "--output", type=Path, required=True, help="output folder (created)")
    parser.add_argument("--model", type=Path, default=None, help="model file (.npz, HIFI3D++ .mat, AI-NExT .mat); default: $FACEGEO_MODEL or the bundled ICT-FaceKit model")
    parser.add_argument("--landmarks", choices=["hybrid", "dlib", "mediapipe"], default="hybrid", help="landmark detector (default: hybrid = dlib 68 + MediaPipe 20 lip points; mediapipe is licence-clean for commercial use)")
    parser.add_argument("--focal", type=float, default=None, help="focal length in pixels of the (possibly downscaled) photo; default: 40° field of view on the long side")
    parser.add_argument("--max-side", type=int, default=2048, help="downscale photos whose longer side exceeds this (pixels)")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with all subcommands."""
    parser = argparse.ArgumentParser(prog="facegeo", description="One photo of a face in, a measured 3D face out.")
    parser.add_argument("--version", action="version", version=f"facegeo {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    fit = sub.add_parser(
        "fit",
        help="fit the morphable model to a photo (fit.json, mesh.obj, overlay.png)",
        description="Detect 88 landmarks, fit pose, identity, expression, albedo and SH lighting, "
        "and write fit.json (parameters, camera, per-point landmark errors, timings), mesh.obj "
        "(posed mesh in camera space, mm, with UVs) and overlay.png.",
    )
    add_fit_arguments(fit)
    fit.add_argument("--no-photometric", action="store_true", help="skip the albedo and lighting stage")
    fit.set_defaults(run=_run_fit)

    rec = sub.add_parser(
        "reconstruct",
        help="photo -> fit -> UV maps -> USD/glTF asset (the whole pipeline)",
        description="Fit the model, unwrap the photo into UV space, complete and de-light the texture, "
        "estimate PBR maps (albedo, normal, roughness, specular, displacement) and write fit.json, "
        "the maps (asset.json + PNGs, re-exportable with 'facegeo export'), the assets and preview.png "
        "(the asset relit from three directions next to the photo).",
    )
    rec.add_argument("photo", type=Path, help="the photo")
    rec.add_argument("-o", "--output", type=Path, required=True, help="output folder (created)")
    rec.add_argument("--backend", choices=["default"], default="default", help="texture backend (default: weight-free, offline)")
    rec.add_argument("--size", type=int, default=1024, help="UV map size in texels (default 1024)")
    rec.add_argument("--upscale", type=int, choices=[1, 2, 4], default=1, help="upscale the maps by this factor (Lanczos)")
    rec.add_argument("--subdiv", type=int, choices=[0, 1, 2, 3], default=0, help="Loop subdivision levels of the exported mesh (displacement baked)")
    rec.add_argument("--maps", default="albedo,normal,roughness,specular,displacement", help="comma-separated maps to compute and export")
    rec.add_argument("--format", default="usdz,glb", help="comma-separated formats among usdz, usdc, usda, glb (default usdz,glb)")
    rec.add_argument("--model", type=Path, default=None, help="model file (see 'facegeo fit --help')")
    rec.add_argument("--landmarks", choices=["hybrid", "dlib", "mediapipe"], default="hybrid", help="landmark detector")
    rec.add_argument("--max-side", type=int, default=2048, help="downscale photos whose longer side exceeds this (pixels)")
    rec.add_argument("--no-preview", action="store_true", help="do not render preview.png")
    rec.set_defaults(run=_run_reconstruct)

    from facegeo.eval.realy_cli import register as register_realy
    from facegeo.export.cli import register as register_export
    from facegeo.uv.cli import register as register_unwrap

    register_unwrap(sub)
    register_export(sub)
    register_realy(sub)
    return parser


def _run_fit(args: argparse.Namespace) -> None:
    from facegeo.camera import Camera
    from facegeo.export.textures import png_bytes
    from facegeo.fitting import fit
    from facegeo.landmarks.scheme import inter_ocular_distance
    from facegeo.mesh_io import obj_text
    from facegeo.model_files import load_model
    from facegeo.overlay import draw_overlay
    from facegeo.photo import load_photo
    from facegeo.staged_output import StagedOutput

    start = time.perf_counter()
    photo = load_photo(args.photo, max_side=args.max_side)
    t_model = time.perf_counter()
    model = load_model(args.model)
    model_seconds = time.perf_counter() - t_model
    height, width = photo.image.shape[:2]
    camera = Camera.for_image(width, height)
    if args.focal is not None:
        camera = Camera(args.focal, width / 2.0, height / 2.0, width, height)
    result = fit(photo, model=model, detector=args.landmarks, camera=camera, photometric=not args.no_photometric)
    result.timings["load_model"] = model_seconds
    result.timings["total"] = time.perf_counter() - start
    iod = inter_ocular_distance(result.landmarks)
    result.info["landmark_rms_percent_iod"] = 100.0 * result.landmark_rms_px / iod
    with StagedOutput(args.output) as stage:
        stage.path("fit.json").write_text(json.dumps(result.to_dict(), indent=1))
        stage.path("mesh.obj").write_text(obj_text(result.vertices, model.triangles, model.uv, model.uv_triangles))
        overlay = draw_overlay(photo.image, result, model)
        stage.path("overlay.png").write_bytes(png_bytes(overlay))
    for note in result.info.get("notes", []):
        print(f"note: {note}")
    print(
        f"fitted {args.photo} with {model.name}: "
        f"landmark RMS {result.landmark_rms_px:.2f} px = {result.info['landmark_rms_percent_iod']:.2f} % of the inter-ocular distance"
    )
    print("timings: " + ", ".join(f"{k} {v:.3f} s" for k, v in result.timings.items()))
    print(f"wrote {args.output}/fit.json, mesh.obj, overlay.png")


def _run_reconstruct(args: argparse.Namespace) -> None:
    from tqdm import tqdm

    from facegeo.asset import MAP_NAMES
    from facegeo.errors import InputError
    from facegeo.export.asset_io import write_asset_files
    from facegeo.export.textures import png_bytes
    from facegeo.export.writers import FORMATS, export_asset
    from facegeo.model_files import load_model
    from facegeo.photo import load_photo
    from facegeo.errors import NoFaceError
    from facegeo.pipeline import STAGES, reconstruct_with_fit, relit_preview
    from facegeo.skin_mask import skin_mask, skin_mask_image
    from facegeo.staged_output import StagedOutput

    maps = [m.strip() for m in args.maps.split(",") if m.strip()]
    formats = [f.strip().lower().lstrip(".") for f in args.format.split(",") if f.strip()]
    for name in maps:
        if name not in MAP_NAMES:
            raise InputError("<command line>", "--maps", f"names among {', '.join(MAP_NAMES)}", repr(name))
    for f in formats:
        if f not in FORMATS:
            raise InputError("<command line>", "--format", f"formats among {', '.join(FORMATS)}", repr(f))
    start = time.perf_counter()
    photo = load_photo(args.photo, max_side=args.max_side)
    model = load_model(args.model)
    bar = tqdm(total=len(STAGES) + 2, desc="reconstruct", unit="stage", disable=not sys.stderr.isatty(), leave=False)

    def progress(stage: str) -> None:
        bar.set_postfix_str(stage)
        bar.update(1)

    try:  # the skin mask needs MediaPipe's mesh; without it the pipeline builds one from the fit's landmarks
        skin = skin_mask(photo.image, source=str(args.photo))
    except NoFaceError:
        skin = None
    asset, result = reconstruct_with_fit(photo, model, backend=args.backend, size=args.size, upscale=args.upscale,
                                maps=maps, detector=args.landmarks, skin=skin, progress=progress)
    timings = dict(asset.metadata["timings_s"])
    with StagedOutput(args.output) as stage:
        bar.set_postfix_str("export")
        bar.update(1)
        t = time.perf_counter()
        write_asset_files(asset, stage.staging_dir)
        if skin is not None:
            stage.path("skin_mask.png").write_bytes(png_bytes(skin_mask_image(skin)))
        # An 11k-vertex mesh cannot carry texel-scale displacement: at --subdiv 0 the detail
        # travels in the normal map only (the displacement map stays in the asset folder).
        carried = [m for m in asset.maps if m != "displacement" or args.subdiv > 0]
        for fmt in formats:
            export_asset(asset, stage.path(f"face.{fmt}"), format=fmt, level=args.subdiv, maps=carried)
        timings["export"] = time.perf_counter() - t
        if not args.no_preview:
            bar.set_postfix_str("preview")
            bar.update(1)
            t = time.perf_counter()
            preview = relit_preview(photo.image, asset, result, model)
            stage.path("preview.png").write_bytes(png_bytes(preview))
            timings["preview"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - start
        record = result.to_dict()
        record["timings_s"] = {**record["timings_s"], "stages": timings}
        record["texture_report"] = asset.metadata.get("texture_report", {})
        stage.path("fit.json").write_text(json.dumps(record, indent=1))
    bar.close()
    for note in result.info.get("notes", []):
        print(f"note: {note}")
    print(f"reconstructed {args.photo}: landmark RMS {result.landmark_rms_px:.2f} px, maps {', '.join(asset.maps)} "
          f"at {next(iter(asset.maps.values())).shape[0]}², formats {', '.join(formats)}")
    print("timings: " + ", ".join(f"{k} {v:.2f} s" for k, v in timings.items()))
    print(f"wrote {args.output}")


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``facegeo`` console command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        args.run(args)
    except FacegeoError as exc:
        print(f"facegeo: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("facegeo: interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
