"""``facegeo unwrap PHOTO -o OUT``: fit the model to a photo, then unwrap the photo into UV space.

Writes (atomically, through :class:`facegeo.staged_output.StagedOutput`):

| file | content |
|---|---|
| ``texture_incomplete.png`` | T_inc, 8-bit sRGB RGB (the photo's values; black where M_vis = 0) |
| ``visibility.png`` | M_vis, 8-bit grey (255 = fully visible; the skin mask folded in) |
| ``skin_mask.png`` | the photo's skin mask (:mod:`facegeo.skin_mask`), 8-bit grey, photo size: 255 = the face's own surface, 0 = hair, glasses, clothing, eye interiors, mouth opening |
| ``position.exr`` | position map, float32 RGB = camera-space x, y, z in mm |
| ``normal.exr`` | normal map, float32 RGB = unit camera-space normal (0 where no surface) |
| ``tangent.exr`` | float32 RGBA = MikkTSpace tangent x, y, z and bitangent sign (±1) |
| ``unwrap.json`` | size, padding, frame, pose, camera, coverage statistics, timings |

The geometry maps are in the camera space of the fit (the frame of ``facegeo fit``'s
``mesh.obj``); ``unwrap.json`` holds the rotation and translation back to model space.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from facegeo.commands.arguments import COMMAND_LINE, Command, add_fit_arguments, add_photo_arguments
from facegeo.errors import InputError

__all__ = ["COMMANDS", "OUTPUT_FILES"]

#: The files ``facegeo unwrap`` writes.
OUTPUT_FILES = ("texture_incomplete.png", "visibility.png", "skin_mask.png", "position.exr", "normal.exr", "tangent.exr", "unwrap.json")


def _arguments(parser: argparse.ArgumentParser) -> None:
    add_photo_arguments(parser)
    add_fit_arguments(parser)
    parser.add_argument("--size", type=int, default=1024, help="UV map size in texels (default 1024)")
    parser.add_argument("--padding", type=int, default=None, help="seam padding in texels (default size/128, at least 2)")
    parser.add_argument("--occlusion", type=Path, default=None, help="optional image-space mask, same size as the photo: white where hair, glasses or hands cover the face (added to the skin mask's occlusion)")
    parser.add_argument("--no-skin-mask", action="store_true", help="do not compute the skin mask (M_vis is then geometric visibility only, times --occlusion)")


def _run(args: argparse.Namespace) -> None:
    """Run ``facegeo unwrap`` for parsed ``args`` (raises :class:`facegeo.errors.FacegeoError`),
    holding the output folder's lock from the start (a second run into it is refused before it fits)."""
    from facegeo.staged_output import locked_output

    with locked_output(args.output):
        _unwrap(args)


def _unwrap(args: argparse.Namespace) -> None:
    """The work of :func:`_run`."""
    from facegeo.camera import euler_from_rotation
    from facegeo.fitting import fit
    from facegeo.image_files import exr_bytes, png_bytes
    from facegeo.jobs import photo_camera
    from facegeo.model_files import load_model
    from facegeo.photo import load_photo
    from facegeo.skin_mask import skin_mask, skin_mask_image
    from facegeo.staged_output import StagedOutput
    from facegeo.uv.maps import geometry_maps
    from facegeo.uv.raster import MAX_SIZE, rasterize_uv
    from facegeo.uv.unwrapping import FACING_RAMP, unwrap_details

    if not 16 <= args.size <= MAX_SIZE:
        raise InputError(COMMAND_LINE, "--size", f"a map size in [16, {MAX_SIZE}] texels", str(args.size))
    if args.padding is not None and args.padding < 0:
        raise InputError(COMMAND_LINE, "--padding", "a number of texels ≥ 0", str(args.padding))
    start = time.perf_counter()
    timings: dict[str, float] = {}
    photo = load_photo(args.photo, max_side=args.max_side)
    occlusion = None
    if args.occlusion is not None:
        mask = load_photo(args.occlusion, max_side=args.max_side).image
        if mask.shape[:2] != photo.image.shape[:2]:
            raise InputError(args.occlusion, "occlusion mask", f"an image of the photo's size {photo.image.shape[1]}x{photo.image.shape[0]}",
                             f"{mask.shape[1]}x{mask.shape[0]}")
        occlusion = mask.astype(np.float32).mean(axis=2) / 255.0
    model = load_model(args.model)
    t = time.perf_counter()
    result = fit(photo, model=model, detector=args.landmarks, camera=photo_camera(photo, args.focal, args.principal_point))
    camera = result.camera
    timings["fit"] = time.perf_counter() - t

    skin = None
    if not args.no_skin_mask:
        t = time.perf_counter()
        skin = skin_mask(photo.image, result.landmarks, source=str(args.photo))
        occlusion = skin.occlusion if occlusion is None else np.maximum(occlusion, skin.occlusion)
        timings["skin_mask"] = time.perf_counter() - t

    t = time.perf_counter()
    raster = rasterize_uv(model, size=args.size, padding=args.padding)
    timings["rasterize_uv"] = time.perf_counter() - t
    t = time.perf_counter()
    maps = geometry_maps(result.vertices, model, raster)
    timings["geometry_maps"] = time.perf_counter() - t
    t = time.perf_counter()
    unwrapped = unwrap_details(photo.image, result, model, maps=maps, occlusion=occlusion)
    timings["unwrap"] = time.perf_counter() - t

    texture, vis = unwrapped.texture, unwrapped.visibility
    yaw, pitch, roll = euler_from_rotation(result.rotation)
    inside = raster.inside
    info = {
        "size": raster.size,
        "padding": raster.padding,
        "photo": str(args.photo),
        "model": model.name,
        "colour_space": {"texture_incomplete.png": "sRGB (the photo's values)", "exr": "linear float32"},
        "frame": "camera space of the fit, mm; model space X = R^T (X_c - t)",
        "rotation": np.asarray(result.rotation).tolist(),
        "translation_mm": np.asarray(result.translation).tolist(),
        "euler_deg": {"yaw": yaw, "pitch": pitch, "roll": roll},
        "camera": camera.as_dict(),
        "facing_ramp": list(FACING_RAMP),
        "texels_inside": int(inside.sum()),
        "texels_visible": int((unwrapped.visible & inside).sum()),
        "mean_visibility_inside": float(vis[inside].mean()) if inside.any() else 0.0,
        "landmark_rms_px": float(result.landmark_rms_px),
        "skin_mask": skin.summary() if skin is not None else None,
    }
    t = time.perf_counter()
    with StagedOutput(args.output, replace=True) as stage:
        rgb8 = np.clip(np.round(texture * 255.0), 0, 255).astype(np.uint8)
        stage.path("texture_incomplete.png").write_bytes(png_bytes(rgb8))
        stage.path("visibility.png").write_bytes(png_bytes(np.clip(np.round(vis * 255.0), 0, 255).astype(np.uint8)))
        if skin is not None:
            stage.path("skin_mask.png").write_bytes(png_bytes(skin_mask_image(skin)))
        stage.path("position.exr").write_bytes(exr_bytes(maps.position))
        stage.path("normal.exr").write_bytes(exr_bytes(maps.normal))
        tangent = np.concatenate([maps.tangent, maps.bitangent_sign[..., None]], axis=-1)
        stage.path("tangent.exr").write_bytes(exr_bytes(tangent))
        timings["write"] = time.perf_counter() - t
        timings["total"] = time.perf_counter() - start
        info["timings_s"] = timings
        stage.path("unwrap.json").write_text(json.dumps(info, indent=1))
    print(f"unwrapped {args.photo} at {raster.size}x{raster.size}: "
          f"{info['texels_visible']} of {info['texels_inside']} texels visible, landmark RMS {result.landmark_rms_px:.2f} px")
    print("timings: " + ", ".join(f"{k} {v:.3f} s" for k, v in timings.items()))
    print(f"wrote {args.output}/" + ", ".join(f for f in OUTPUT_FILES if skin is not None or f != "skin_mask.png"))


COMMANDS = (
    Command(
        "unwrap",
        help="fit, then unwrap the photo into UV space (texture_incomplete.png, visibility.png, geometry EXRs)",
        description="Fit the morphable model to the photo, then write the incomplete texture T_inc "
        "(texture_incomplete.png, sRGB), its visibility M_vis (visibility.png), and the position, normal and "
        "MikkTSpace tangent maps of the fitted mesh as float32 EXR (camera space, mm), plus unwrap.json.",
        arguments=_arguments,
        run=_run,
        output_folder=True,
    ),
)
