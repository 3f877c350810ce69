"""One albedo from several photos (issue 48, ``facegeo reconstruct --one-person``) against a real
skin colour map: Blender renders of two real head scans (``bench_albedo_scans.py``'s renders and
3-D truth) at yaw 0°, ±20°, ±40°, fitted jointly (:func:`facegeo.fitting.fit_photos`), the albedo
fused from all five (:func:`facegeo.pipeline.reconstruct_views`) compared with the albedo of the
reference photo alone (the frontal one, on the same joint fit: the same geometry, so the same
truth map) and with a flat colour of the seen skin's median.

Truth: the reference fit's mesh similarity-aligned to the scan on the texels the reference photo
sees, then the scan's colour at the nearest scan points (``Truth3D`` of ``bench_albedo_scans``).
One exposure scale per method (its luminance least-squares onto the truth's over the skin the
reference sees). Skin texels are split by what the reference photo saw:

* **seen**: skin the frontal photo sees (M_vis > 0.5);
* **sides**: skin it does not see that another photo does (M_vis > 0.5 in one of them): what a
  single photo has to invent and several photos can show;
* **unseen**: skin no photo sees (filled by the reference's backend in both).

Per region the median CIEDE2000, and on all skin the gradient ratio (|∇Lab| of the albedo over
the truth's, both blurred by the reference photo's pixel footprint) and the seam ratio (|∇Lab|
within 3 texels of the reference's seen/unseen boundary over the rest).

    python benchmarks/bench_albedo_views.py [--scans james lee_perry_smith] [--light even] [--dump DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy import ndimage
from skimage.color import deltaE_ciede2000

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_albedo_scans import SCAN_LABELS, Truth3D, exposure, gradient, lab, photo_of, view_for  # noqa: E402
from scan_evaluation import similarity_transform  # noqa: E402

import facegeo  # noqa: E402
from facegeo.colour import linear_to_srgb, srgb_to_linear  # noqa: E402
from facegeo.fitting import fit_photos  # noqa: E402
from facegeo.pipeline import reconstruct_views, reconstruct_with_fit  # noqa: E402
from facegeo.skin_mask import skin_vertex_mask  # noqa: E402
from facegeo.texturing.context import surface_operators  # noqa: E402
from facegeo.texturing.image_filters import masked_blur  # noqa: E402
from facegeo.uv import geometry_maps, rasterize_uv, unwrap_details  # noqa: E402

RENDERS = ("yaw+00", "yaw+20", "yaw-20", "yaw+40", "yaw-40")


class Given:
    """A fitter that returns the fit already made."""

    def __init__(self, fit):
        self.fit = fit

    def __call__(self, photo, **_):
        return self.fit


def evaluate(scan: str, light: str, model, raster, skin_texels, dump: Path | None) -> dict:
    S = raster.size
    views = [view_for(scan, r) for r in RENDERS]
    photos = [photo_of(v, light) for v in views]
    t = time.perf_counter()
    fits = fit_photos(photos, model)
    fit_seconds = time.perf_counter() - t
    t = time.perf_counter()
    fused_asset, ref, report = reconstruct_views(photos, fits, model, size=S, maps={"albedo"}, parts=False)
    views_seconds = time.perf_counter() - t
    view, photo, fit = views[ref], photos[ref], fits[ref]
    single_asset, _ = reconstruct_with_fit(photo, model, fitter=Given(fit), size=S, maps={"albedo"}, parts=False)
    cover = np.asarray(raster.inside)
    seen_by = [unwrap_details(p, f, model, raster=raster).visibility > 0.5 for p, f in zip(photos, fits)]
    un = unwrap_details(photo, fit, model, raster=raster)
    seen = cover & seen_by[ref]
    # 3-D truth: the reference fit aligned to the scan on the texels the reference photo sees
    position = geometry_maps(fit.vertices, model, raster, tangents=False).position
    idx = np.flatnonzero(seen.ravel())
    xy = un.pixel[seen]
    px = np.clip(np.floor(xy).astype(int), 0, [view.camera.width - 1, view.camera.height - 1])
    target = view.points[px[:, 1], px[:, 0]]
    source = position.reshape(-1, 3)[idx]
    good = np.all(np.isfinite(target), axis=1) & view.mask[px[:, 1], px[:, 0]]
    source, target = source[good], target[good]
    keep = np.ones(len(source), bool)
    for _ in range(4):
        s, R, tr = similarity_transform(source[keep], target[keep])
        residual = np.linalg.norm(source @ R.T * s + tr - target, axis=1)
        keep = residual <= np.quantile(residual, 0.8)
    colour, near = Truth3D.build(scan).lookup(position[cover] @ R.T * s + tr)
    truth = np.zeros((S, S, 3), np.float32)
    truth[cover] = colour
    truth_ok = np.zeros((S, S), bool)
    truth_ok[cover] = near
    skin = skin_texels & truth_ok
    any_other = np.any([m for k, m in enumerate(seen_by) if k != ref], axis=0)
    regions = {"seen": skin & seen, "sides": skin & ~seen & any_other, "unseen": skin & ~seen & ~any_other}
    albedos = {"fused": srgb_to_linear(fused_asset.maps["albedo"]), "single": srgb_to_linear(single_asset.maps["albedo"])}
    t_inc = srgb_to_linear(un.texture)
    albedos["flat"] = np.broadcast_to(np.median(t_inc[seen & skin], axis=0), (S, S, 3)).astype(np.float32)
    texel_mm = float(np.median(np.linalg.norm(np.gradient(position, axis=1), axis=-1)[cover]))
    blur = max(0.5, float(np.median(-position[seen][:, 2])) / fit.camera.focal / texel_mm)
    g_truth = gradient(lab(masked_blur(truth, skin, blur)), skin)
    boundary = ndimage.binary_dilation(seen | ~cover, iterations=3) & ndimage.binary_dilation(~seen & cover, iterations=3) & skin
    rest = skin & ~ndimage.binary_dilation(boundary, iterations=6)
    lab_truth = lab(truth)
    out = {"scan": scan, "light": light, "reference": RENDERS[ref], "fit_s": fit_seconds, "views_s": views_seconds,
           "texels": {k: int(v.sum()) for k, v in regions.items()}, "fusion": report, "methods": {}}
    for method, albedo in albedos.items():
        scaled = albedo * exposure(albedo[regions["seen"]], truth[regions["seen"]])
        la = lab(scaled)
        row = {f"de_{name}": float(np.median(deltaE_ciede2000(la[m], lab_truth[m]))) if m.any() else float("nan")
               for name, m in regions.items()}
        if method != "flat":
            g = gradient(lab(masked_blur(scaled, skin, blur)), skin)
            row["gradient"] = float(np.nanmean(g[skin]) / np.nanmean(g_truth[skin]))
            row["seam"] = float(np.nanmean(g[boundary]) / np.nanmean(g[rest]))
        out["methods"][method] = row
    out["truth_seam"] = float(np.nanmean(g_truth[boundary]) / np.nanmean(g_truth[rest]))
    if dump is not None:
        import cv2

        dump.mkdir(parents=True, exist_ok=True)
        tiles = [truth] + [albedos[m] * exposure(albedos[m][regions["seen"]], truth[regions["seen"]]) for m in ("single", "fused")]
        tiles = [np.where(skin[..., None], linear_to_srgb(np.clip(t, 0, 1)), 0.3) for t in tiles]
        cv2.imwrite(str(dump / f"{scan}_{light}.png"),
                    cv2.cvtColor((np.concatenate(tiles, 1)[::2, ::2] * 255).astype(np.uint8), cv2.COLOR_RGB2BGR))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", nargs="+", default=list(SCAN_LABELS), choices=list(SCAN_LABELS))
    ap.add_argument("--light", default="even", choices=["even", "warm"])
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--dump", type=Path, default=None, help="write truth | single | fused UV maps here")
    args = ap.parse_args(argv)
    model = facegeo.load_model()
    raster = rasterize_uv(model, size=args.size)
    surf = surface_operators(model, raster)
    skin_texels = (surf.to_texels(skin_vertex_mask(model).astype(np.float32), args.size) > 0.5) & np.asarray(raster.inside)
    rows = []
    for scan in args.scans:
        row = evaluate(scan, args.light, model, raster, skin_texels, args.dump)
        rows.append(row)
        print(json.dumps(row), file=sys.stderr)
    print(f"command: `python benchmarks/bench_albedo_views.py {' '.join(sys.argv[1:] if argv is None else argv)}`; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}; S = {args.size}")
    print("| scan | method | ΔE00 seen | ΔE00 sides | ΔE00 unseen | gradient | seam |")
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        for method, r in row["methods"].items():
            print(f"| {SCAN_LABELS[row['scan']]} | {method} | {r['de_seen']:.2f} | {r['de_sides']:.2f} | {r['de_unseen']:.2f} | "
                  f"{r.get('gradient', float('nan')):.2f} | {r.get('seam', float('nan')):.2f} |")
        print(f"| {SCAN_LABELS[row['scan']]} | (texels) | {row['texels']['seen']} | {row['texels']['sides']} | {row['texels']['unseen']} | "
              f"truth seam {row['truth_seam']:.2f} | fit {row['fit_s']:.1f} s, views {row['views_s']:.1f} s |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
