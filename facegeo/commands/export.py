"""``facegeo export ASSET_DIR -o FILE``: re-export a saved asset folder to USD or glTF.

Errors are :class:`FacegeoError` (one line, exit status 2, no output left behind), as for every
facegeo command.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from facegeo.commands.arguments import COMMAND_LINE, Command, add_blendshape_arguments, add_parts_argument, parse_list
from facegeo.errors import InputError

__all__ = ["COMMANDS"]


def _arguments(parser: argparse.ArgumentParser) -> None:
    from facegeo.asset import MAP_NAMES
    from facegeo.export.writers import FORMATS

    parser.add_argument("asset_dir", type=Path, metavar="ASSET_DIR", help="folder with asset.json")
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="FILE",
                        help="output file; its suffix picks the format, or give --format (several formats: FILE is the stem)")
    parser.add_argument("--format", default=None, metavar="FMT[,FMT]",
                        help=f"format(s), comma-separated, among {', '.join(FORMATS)} (default: the suffix of FILE)")
    parser.add_argument("--subdiv", type=int, choices=[0, 1, 2, 3], default=0, help="Loop subdivision levels before baking the displacement (default 0)")
    parser.add_argument("--maps", default=None, metavar="NAME[,NAME]",
                        help=f"maps to carry, among {', '.join(MAP_NAMES)} (default: all the asset has)")
    parser.add_argument("--displacement", choices=["bake", "texture"], default="bake",
                        help="bake the displacement into the geometry (default) or, USD only, write it as the material's displacement input")
    add_parts_argument(parser)
    add_blendshape_arguments(parser)


def _run(args: argparse.Namespace) -> None:
    """Run ``facegeo export`` with parsed arguments (raises FacegeoError on bad input).

    The output files are checked and locked (one run at a time per file,
    :func:`facegeo.staged_output.locked_output`) before the asset is read, written into one
    staging folder and moved into place together: with several formats, either all files appear
    or none does."""
    import contextlib

    from facegeo.asset import MAP_NAMES
    from facegeo.export.asset_io import load_asset
    from facegeo.export.textures import TextureFiles
    from facegeo.export.writers import FORMATS, export_scenes
    from facegeo.staged_output import StagedOutput, check_output_location, locked_output

    start = time.perf_counter()
    maps = parse_list(args.maps, MAP_NAMES, "--maps") if args.maps is not None else None
    out = Path(args.output)
    if args.format is not None:
        formats = parse_list(args.format, FORMATS, "--format")
        if len(formats) > 1 and out.suffix.lower().lstrip(".") in FORMATS:
            out = out.with_suffix("")
        if len(formats) > 1 or not out.suffix:
            targets = [(out.with_name(out.name + "." + f), f) for f in formats]
        else:
            targets = [(out, formats[0])]
    else:
        fmt = out.suffix.lower().lstrip(".")
        if fmt not in FORMATS:
            raise InputError(out, "file name", f"a suffix among {', '.join('.' + f for f in FORMATS)} (or --format)", out.suffix or "none")
        targets = [(out, fmt)]
    if args.displacement == "texture" and any(f == "glb" for _, f in targets):
        raise InputError(COMMAND_LINE, "--displacement", "'bake' when writing glb (glTF has no displacement input)", "texture")
    for path, fmt in targets:  # before any work: names, parents, an existing folder in the way
        check_output_location(path, folder=False, extra_names=[path.stem + "_textures"] if fmt in ("usda", "usdc") else [])
    with contextlib.ExitStack() as locks:
        for path, _ in sorted(targets):
            locks.enter_context(locked_output(path, "output file"))
        texture_files = TextureFiles()  # the folder's PNGs, embedded as they are where the scenes want their pixels
        asset = load_asset(args.asset_dir, texture_files=texture_files).select(args.parts)
        with StagedOutput(out.parent) as stage:
            export_scenes(asset, [(stage.path(path.name), fmt) for path, fmt in targets], level=args.subdiv,
                          displacement=args.displacement, maps=maps, blendshapes=None if args.blendshapes == "none" else args.blendshape_names,
                          texture_files=texture_files)
    seconds = time.perf_counter() - start
    print(f"wrote {', '.join(str(path) for path, _ in targets)} from {args.asset_dir} "
          f"(parts {args.parts}, subdivision level {args.subdiv}, {seconds:.2f} s)")


COMMANDS = (
    Command(
        "export",
        help="re-export a saved asset folder (asset.json, mesh.obj, maps) to usdz/usdc/usda/glb",
        description="Read an asset folder written by facegeo (asset.json, mesh.obj with UVs, the maps as "
        "8/16-bit PNG) and write it as USD (usdz, usdc, usda; UsdPreviewSurface, Y-up, mm) or glTF 2.0 "
        "binary (glb; metres, metallic-roughness PBR, KHR_materials_specular). Only the maps the "
        "asset has (or --maps names) are written; constant maps become material factors.",
        arguments=_arguments,
        run=_run,
    ),
)
