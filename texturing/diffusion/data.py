"""Paired training data (the paper's Sec. 3.1) made with the project's own renderer and shader.

A **PBR set** is a folder with ``albedo.png`` (sRGB), ``normal.png`` (tangent space, n·0.5 + 0.5,
OpenGL), ``roughness.png``, ``specular.png`` (grey, [0, 1]) and ``displacement.png`` (grey, 0.5 =
no displacement, 0 and 1 = ∓ ``displacement_mm``), 8- or 16-bit, square, all one size (the
layout of the bundled model's UVs). For every set and sample, :func:`make_pair` draws a random
identity, pose and lighting and produces, in UV at size S:

- ``t_env``: the set shaded with :func:`facegeo.texturing.shading.shade_ggx` on the posed mesh
  under 1–3 random directional lights and an ambient term (the baked environment lighting);
- ``t_inc``, ``m_vis``: the mesh rendered with ``t_env`` into the camera
  (:func:`facegeo.uv.render`) and unwrapped back (:func:`facegeo.uv.unwrap`): the incomplete
  texture (multiplied by the visibility) and its visibility;
- ``t_hom``: the set shaded under uniform white light (64 directional lights evenly over the
  sphere, radiance 4π/64 each, so a Lambertian texel gets its albedo back) on the same geometry;
- the PBR targets: ``albedo``, ``normal`` and the packed ``rsd`` image (:func:`pack_rsd`).

A sample folder holds ``t_inc.png``, ``m_vis.png``, ``t_env.png``, ``t_hom.png``, ``albedo.png``
(8-bit sRGB) and ``normal.png``, ``rsd.png`` (16-bit), the images the LoRAs train on.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import torch

from facegeo.asset import MAP_NAMES
from facegeo.camera import Camera, rotation_from_euler
from facegeo.colour import linear_to_srgb, srgb_to_linear
from facegeo.errors import InputError
from facegeo.image_files import png_bytes, read_png, to_uint
from facegeo.staged_output import StagedOutput
from facegeo.texturing.default.materials import normal_from_height
from facegeo.texturing.shading import shade_ggx
from facegeo.uv import geometry_maps, rasterize_uv, render, unwrap

__all__ = [
    "RSD_DISPLACEMENT_MM",
    "SAMPLE_FILES",
    "pack_rsd",
    "unpack_rsd",
    "procedural_pbr_set",
    "write_pbr_set",
    "read_pbr_set",
    "uniform_white_lights",
    "make_pair",
    "make_texture_pairs",
    "read_samples",
]

#: Displacement range of the packed ``rsd`` image: its blue channel 0..1 is −1..+1 mm.
RSD_DISPLACEMENT_MM = 1.0
#: The images of one training sample (all (S, S, 3) but ``m_vis``, (S, S)).
SAMPLE_FILES = ("t_inc", "m_vis", "t_env", "t_hom", "albedo", "normal", "rsd")
_PBR_FILES = {name: f"{name}.png" for name in MAP_NAMES}


def pack_rsd(roughness: np.ndarray, specular: np.ndarray, displacement_mm: np.ndarray) -> np.ndarray:
    """(S, S) roughness [0, 1], specular [0, 1], displacement (mm) -> (S, S, 3) image in [0, 1]:
    R = roughness, G = specular, B = displacement/(2·RSD_DISPLACEMENT_MM) + 0.5 (clipped)."""
    blue = displacement_mm / (2.0 * RSD_DISPLACEMENT_MM) + 0.5
    return np.clip(np.stack([roughness, specular, blue], axis=-1), 0.0, 1.0).astype(np.float32)


def unpack_rsd(rsd: np.ndarray) -> dict[str, np.ndarray]:
    """Inverse of :func:`pack_rsd` (values clipped to the image range first): roughness and
    specular in [0, 1], displacement in [−RSD_DISPLACEMENT_MM, +RSD_DISPLACEMENT_MM] mm."""
    x = np.clip(rsd, 0.0, 1.0).astype(np.float32)
    return {"roughness": x[..., 0], "specular": x[..., 1], "displacement": (x[..., 2] - 0.5) * 2.0 * RSD_DISPLACEMENT_MM}


def _smooth_noise(rng: np.random.Generator, size: int, sigma: float) -> np.ndarray:
    """(S, S) Gaussian-filtered white noise scaled to unit standard deviation."""
    n = cv2.GaussianBlur(rng.standard_normal((size, size)).astype(np.float32), (0, 0), sigma)
    return n / max(float(n.std()), 1e-6)


def procedural_pbr_set(size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """A random skin-like PBR set in the asset conventions (:mod:`facegeo.asset`): a skin tone with
    blotches and freckles, pore-scale displacement (within ±0.1 mm), the normal map of that relief,
    and roughness/specular that vary smoothly and with the pores."""
    tone = np.array([0.80, 0.58, 0.47]) * rng.uniform(0.45, 1.1) + rng.normal(0, 0.03, 3)
    blotch = _smooth_noise(rng, size, size / 16)
    freckles = np.maximum(_smooth_noise(rng, size, 1.0) - 2.0, 0.0)
    albedo_lin = srgb_to_linear(np.clip(tone, 0.05, 0.95)) * (1 + 0.08 * blotch[..., None])
    albedo_lin *= 1 - 0.3 * np.clip(freckles, 0, 1)[..., None] * np.array([0.6, 0.8, 1.0])
    pores = _smooth_noise(rng, size, max(0.7, size / 256))
    displacement = np.clip(0.02 * pores + 0.03 * _smooth_noise(rng, size, size / 32), -0.1, 0.1).astype(np.float32)
    mm_per_texel = 250.0 / size  # the bundled UV square spans about 25 cm of head surface
    ctx = SimpleNamespace(texel_size_mm=np.full((size, size, 2), mm_per_texel, np.float32))
    normal = normal_from_height(displacement, ctx)
    roughness = np.clip(0.5 + 0.08 * _smooth_noise(rng, size, size / 24) + 0.05 * pores, 0.1, 0.95)
    specular = np.clip(0.5 + 0.1 * _smooth_noise(rng, size, size / 24) - 0.05 * pores, 0.05, 1.0)
    return {
        "albedo": linear_to_srgb(albedo_lin),
        "normal": normal,
        "roughness": roughness.astype(np.float32),
        "specular": specular.astype(np.float32),
        "displacement": displacement,
    }


def write_pbr_set(folder: str | os.PathLike[str], maps: dict[str, np.ndarray], displacement_mm: float = 0.1) -> None:
    """Write a PBR set (asset conventions) as the files :func:`read_pbr_set` reads (16-bit),
    atomically."""
    images = {
        "albedo": maps["albedo"],
        "normal": maps["normal"] * 0.5 + 0.5,
        "roughness": maps["roughness"],
        "specular": maps["specular"],
        "displacement": maps["displacement"] / (2.0 * displacement_mm) + 0.5,
    }
    with StagedOutput(folder) as stage:
        for name, image in images.items():
            stage.path(_PBR_FILES[name]).write_bytes(png_bytes(to_uint(image, 16)))


def read_pbr_set(folder: str | os.PathLike[str], size: int, displacement_mm: float = 0.1) -> dict[str, np.ndarray]:
    """A PBR set folder (module docstring) resized to ``size`` -> maps in the asset conventions.

    Raises:
        InputError: a missing file, or an image that is not square or not the set's size.
    """
    root = Path(folder)
    out: dict[str, np.ndarray] = {}
    shape = None
    for name, file in _PBR_FILES.items():
        path = root / file
        if not path.is_file():
            raise InputError(path, name, f"a PNG image ({', '.join(_PBR_FILES.values())} in every set)", "no such file")
        raw = read_png(str(path))
        image = raw.astype(np.float32) / float(np.iinfo(raw.dtype).max)
        if image.shape[0] != image.shape[1] or (shape is not None and image.shape[:2] != shape):
            raise InputError(path, name, f"a square image of the set's size {shape or 'N×N'}", "×".join(map(str, image.shape[:2])))
        shape = image.shape[:2]
        channels = 3 if name in ("albedo", "normal") else 1
        image = image[..., :3] if image.ndim == 3 else np.repeat(image[..., None], 3, axis=-1)
        image = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
        out[name] = image if channels == 3 else image[..., 0]
    n = out["normal"] * 2.0 - 1.0
    out["normal"] = (n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)).astype(np.float32)
    out["displacement"] = ((out["displacement"] - 0.5) * 2.0 * displacement_mm).astype(np.float32)
    return out


def uniform_white_lights(count: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """``count`` directions evenly over the sphere (Fibonacci lattice), (count, 3), and their
    radiance 4π/count each, (count, 3): Σ_k L (n·l_k)⁺ ≈ π for any n, so f_d = albedo/π shades to
    the albedo."""
    k = np.arange(count) + 0.5
    z = 1.0 - 2.0 * k / count
    phi = np.pi * (1.0 + 5**0.5) * k
    r = np.sqrt(1.0 - z * z)
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1).astype(np.float32)
    return dirs, np.full((count, 3), 4.0 * np.pi / count, np.float32)


def _chw(a: np.ndarray) -> torch.Tensor:
    a = a[..., None] if a.ndim == 2 else a
    return torch.from_numpy(np.ascontiguousarray(a.transpose(2, 0, 1), dtype=np.float32))[None]


def _shade(pbr: dict[str, np.ndarray], geo, dirs: np.ndarray, radiance: np.ndarray, ambient: float) -> np.ndarray:
    """(S, S, 3) sRGB of the set shaded on camera-space geometry maps (camera at the origin)."""
    result = shade_ggx(
        _chw(srgb_to_linear(pbr["albedo"])), _chw(pbr["normal"]), _chw(pbr["roughness"]), _chw(pbr["specular"]),
        _chw(pbr["displacement"]), _chw(geo.position), _chw(geo.normal), _chw(geo.tangent),
        _chw(geo.mask.astype(np.float32)), torch.from_numpy(dirs)[None], torch.from_numpy(radiance)[None],
        torch.zeros(1, 3), ambient, s_disp=1.0,  # displacement and positions both in mm
    )
    return linear_to_srgb(result.shaded[0].numpy().transpose(1, 2, 0))


def make_pair(pbr: dict[str, np.ndarray], model, rng: np.random.Generator, image_size: int = 512) -> dict[str, np.ndarray]:
    """One training sample (module docstring) from a PBR set at size S (the maps' size).

    Random draws: identity coefficients N(0, 0.7²); yaw U(−60°, 60°), pitch U(−20°, 20°), roll
    U(−10°, 10°); the face 450–650 mm from a 40° camera of ``image_size``² pixels; 1–3 lights
    from the camera's hemisphere, radiance 1.5–3 with a random tint; ambient U(0.05, 0.3).
    Returns: name -> image as in :data:`SAMPLE_FILES` (float32, [0, 1]).
    """
    size = pbr["albedo"].shape[0]
    alpha = rng.normal(0.0, 0.7, model.n_id).astype(np.float32)
    shape = model.shape(torch.from_numpy(alpha)).numpy()
    rot = rotation_from_euler(rng.uniform(-60, 60), rng.uniform(-20, 20), rng.uniform(-10, 10))
    centre = shape.mean(axis=0)
    vertices = ((shape - centre) @ rot.T + np.array([0.0, 0.0, -rng.uniform(450, 650)])).astype(np.float32)
    camera = Camera.for_image(image_size, image_size)
    raster = rasterize_uv(model, size=size)
    geo = geometry_maps(vertices, model, raster)
    k = int(rng.integers(1, 4))
    dirs = rng.normal(0, 0.6, (k, 3)) + np.array([0.0, 0.3, 1.0])  # towards the camera side (+Z)
    dirs = (dirs / np.linalg.norm(dirs, axis=1, keepdims=True)).astype(np.float32)
    radiance = (rng.uniform(1.5, 3.0, (k, 1)) * rng.uniform(0.8, 1.2, (k, 3))).astype(np.float32)
    t_env = _shade(pbr, geo, dirs, radiance, float(rng.uniform(0.05, 0.3)))
    photo = render(vertices, model, camera, texture=t_env).image
    t_inc, m_vis = unwrap(np.clip(photo, 0, 1), SimpleNamespace(vertices=vertices, camera=camera), model, size, raster=raster)
    white_dirs, white_radiance = uniform_white_lights()
    t_hom = _shade(pbr, geo, white_dirs, white_radiance, 0.0)
    return {
        "t_inc": (t_inc * m_vis[..., None]).astype(np.float32),
        "m_vis": m_vis.astype(np.float32),
        "t_env": t_env,
        "t_hom": t_hom,
        "albedo": pbr["albedo"],
        "normal": (pbr["normal"] * 0.5 + 0.5).astype(np.float32),
        "rsd": pack_rsd(pbr["roughness"], pbr["specular"], pbr["displacement"]),
    }


def make_texture_pairs(sets: list[tuple[str, dict[str, np.ndarray]]], out: str | os.PathLike[str], samples: int, *,
                       seed: int = 0, image_size: int = 512, model=None, progress=None) -> int:
    """Write ``samples`` pairs per PBR set (``(name, maps)``, maps as :func:`read_pbr_set`
    returns, all one size S) into ``out/<name>_<k>/`` and ``out/pairs.json``, atomically (one
    :class:`StagedOutput` for the folder). Returns the number of pairs."""
    from facegeo.model_files import load_model

    model = load_model() if model is None else model
    rng = np.random.default_rng(seed)
    sizes = {maps["albedo"].shape[0] for _, maps in sets}
    if len(sizes) != 1:
        raise InputError("<argument>", "PBR sets", "sets of one size", ", ".join(map(str, sorted(sizes))) or "none")
    names = []
    with StagedOutput(out) as stage:
        for set_name, pbr in sets:
            for k in range(samples):
                pair = make_pair(pbr, model, rng, image_size)
                name = f"{set_name}_{k:04d}"
                for key, image in pair.items():
                    bits = 16 if key in ("normal", "rsd") else 8
                    stage.path(f"{name}/{key}.png").write_bytes(png_bytes(to_uint(image, bits)))
                names.append(name)
                if progress is not None:
                    progress(name)
        doc = {"format": "facegeo-texture-pairs", "size": sizes.pop(), "samples": names, "rsd_displacement_mm": RSD_DISPLACEMENT_MM}
        stage.path("pairs.json").write_text(json.dumps(doc, indent=1))
    return len(names)


def read_samples(folder: str | os.PathLike[str], files: tuple[str, ...] = SAMPLE_FILES) -> dict[str, np.ndarray]:
    """The pairs written by :func:`make_texture_pairs`: name -> (n, S, S, 3) float32 in [0, 1]
    (``m_vis``: (n, S, S)) for each of ``files``.

    Raises:
        InputError: no ``pairs.json``, or a listed image missing or of another size.
    """
    root = Path(folder)
    meta = root / "pairs.json"
    if not meta.is_file():
        raise InputError(meta, "pairs.json", "a folder written by 'facegeo make-texture-pairs'", "no such file")
    doc = json.loads(meta.read_text())
    size = int(doc["size"])
    out: dict[str, list[np.ndarray]] = {f: [] for f in files}
    for name in doc["samples"]:
        for f in files:
            path = root / name / f"{f}.png"
            if not path.is_file():
                raise InputError(path, f, "an image of the pair", "no such file")
            raw = read_png(str(path))
            if raw.shape[:2] != (size, size):
                raise InputError(path, f, f"{size}×{size} texels", "×".join(map(str, raw.shape[:2])))
            out[f].append(raw.astype(np.float32) / float(np.iinfo(raw.dtype).max))
    return {f: np.stack(v) for f, v in out.items()}
