"""``facegeo animate ASSET_DIR --arkit-csv take.csv -o face_anim.glb|.usdz``: drive a saved asset
with a Live Link Face recording.

The asset folder (``facegeo reconstruct``'s) must carry blendshapes (``blendshapes.npz``). The
take (:func:`facegeo.export.live_link.read_live_link_csv`) becomes glTF ``weights`` channels plus
the head's and eyes' ``rotation`` channels, or UsdSkel time samples (``blendShapeWeights`` and
joint rotations), keyed at the take's times (:mod:`facegeo.export.animation`). Errors are one line
naming the file, the row and the column, exit status 2, nothing written.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from facegeo.commands.arguments import Command, add_blendshape_arguments, add_parts_argument
from facegeo.errors import InputError

__all__ = ["COMMANDS", "ANIMATION_FORMATS"]

#: Output suffixes ``animate`` writes.
ANIMATION_FORMATS = ("glb", "usdz", "usdc", "usda")


def _arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("asset_dir", type=Path, metavar="ASSET_DIR", help="folder with asset.json (facegeo reconstruct's output)")
    parser.add_argument("--arkit-csv", type=Path, required=True, metavar="CSV",
                        help="a Live Link Face recording (Timecode, BlendShapeCount, the 52 ARKit shapes, head and eye rotations)")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                        help=f"the animated file; its suffix picks the format: {', '.join('.' + f for f in ANIMATION_FORMATS)}")
    parser.add_argument("--fps", type=float, default=None, metavar="FPS",
                        help="the take's time code rate, frames per second of the Timecode's frame field (default: the "
                        "clip's rate where facegeo track's track.json lies beside the CSV, else 60, Live Link Face's; the "
                        "app's take JSON records it)")
    parser.add_argument("--clamp", action="store_true", help="clamp weights outside [0, 1] (with a note) instead of refusing the take")
    parser.add_argument("--subdiv", type=int, choices=[0, 1, 2, 3], default=0, help="Loop subdivision levels (default 0)")
    add_parts_argument(parser)
    add_blendshape_arguments(parser, choose=False)


def _run(args: argparse.Namespace) -> None:
    """Read the take, check the output, load the asset and write the animated file (staged)."""
    import numpy as np

    from facegeo.arkit import ARKIT_NAMES, target_naming
    from facegeo.export.asset_io import load_asset
    from facegeo.export.live_link import DEFAULT_FPS, read_live_link_csv
    from facegeo.export.writers import export_asset
    from facegeo.parts import EYEBALLS_PART
    from facegeo.staged_output import StagedOutput, check_output_location

    start = time.perf_counter()
    out = Path(args.output)
    fmt = out.suffix.lower().lstrip(".")
    if fmt not in ANIMATION_FORMATS:
        raise InputError(out, "file name", f"a suffix among {', '.join('.' + f for f in ANIMATION_FORMATS)}", out.suffix or "none")
    check_output_location(out, folder=False, extra_names=[out.stem + "_textures"] if fmt in ("usda", "usdc") else [])
    fps, rate_note = (args.fps, None) if args.fps is not None else _track_rate(Path(args.arkit_csv), DEFAULT_FPS)
    take = read_live_link_csv(args.arkit_csv, fps=fps, clamp=args.clamp)
    asset = load_asset(args.asset_dir).select(args.parts)
    if asset.blendshapes is None:
        raise InputError(Path(args.asset_dir) / "asset.json", "blendshapes",
                         "an asset with blendshapes (written by facegeo reconstruct with the bundled ICT-FaceKit model)", "none")
    naming = target_naming(asset.blendshapes.names, args.blendshape_names)
    with StagedOutput(out.parent) as stage:
        export_asset(asset, stage.path(out.name), format=fmt, level=args.subdiv, blendshapes=args.blendshape_names, animation=take)
    notes = ([rate_note] if rate_note else []) + list(take.notes)
    for name in naming.missing:
        column = ARKIT_NAMES.index(name)
        used = int(np.count_nonzero(take.weights[:, column]))
        if used:
            notes.append(f"{name[0].upper() + name[1:]}: the model has no such shape; its {used} nonzero values are not used")
    if not take.rotations:
        notes.append(f"{take.source}: no head or eye rotation columns; only the blendshapes are animated")
    elif not any(p.name == EYEBALLS_PART for p in asset.parts) and {"left_eye", "right_eye"} & set(take.rotations):
        notes.append(f"--parts {args.parts}: no eyeballs; the eye rotations are not written")
    for note in notes:
        print(f"note: {note}")
    seconds = time.perf_counter() - start
    print(f"wrote {out}: {take.n_frames} frames, {take.times[-1]:.2f} s at {take.fps:g} fps time code, "
          f"{len(naming.names)} {args.blendshape_names} targets ({seconds:.2f} s)")


COMMANDS = (
    Command(
        "animate",
        help="drive a saved asset with a Live Link Face recording (glb or USD animation)",
        description="Read an asset folder written by facegeo reconstruct (with its blendshapes) and a Live Link Face "
        "CSV take, and write the face animated: glTF (glb) morph-target weights and head and eye rotation channels, "
        "or USD (usdz, usdc, usda) with UsdSkel time-sampled blend shape weights and joint rotations.",
        arguments=_arguments,
        run=_run,
    ),
)


def _track_rate(csv: Path, default: float) -> tuple[float, str | None]:
    """The time code rate of a take that ``facegeo track`` wrote (``take.csv`` at the clip's
    rate, ``track.json`` beside it with ``fps``) and a note saying so; ``(default, None)`` where
    no track.json of facegeo's lies beside the CSV. A track.json whose ``fps`` is not a rate > 0
    is an error naming it."""
    import json
    import math

    record_path = csv.parent / "track.json"
    try:
        record = json.loads(record_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError):
        return default, None
    if not (isinstance(record, dict) and "frames_tracked" in record and "fps" in record):
        return default, None  # someone else's file of that name
    fps = record["fps"]
    if isinstance(fps, bool) or not isinstance(fps, (int, float)) or not (math.isfinite(fps) and fps > 0):
        raise InputError(record_path, "fps", "the tracked clip's frames per second (> 0)", repr(fps))
    return float(fps), f"time code rate {fps:g} fps, the tracked clip's ({record_path}; --fps to override)"
