"""Noise on the surface for the fill's detail: 3-D value and gradient noise of the model-space
position (continuous across UV seams), and colour noise with the seen skin's covariance per octave.

Away from the seen skin the fill's detail gets, besides the quilted blocks
(:mod:`~facegeo.texturing.default.quilting`), the octaves from the quilted band's edge up to
``settings.mid_band_coarsest`` × S texels (~12 mm at 1K) as colour noise with the seen skin's own
covariance per octave (:func:`band_noise`: its grain and mottling, which the fill's smooth base
lacks); 3-D value noise of the model-space position (:func:`value_noise`) only where no whole
block of skin was seen.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from facegeo.texturing.default.least_squares import nonnegative_least_squares
from facegeo.texturing.default.settings import DEFAULT_SETTINGS, DefaultSettings
from facegeo.texturing.default.texels import smoothstep
from facegeo.texturing.image_filters import area_mean, masked_blur

__all__ = ["band_noise", "noise_layers", "coloured_noise", "NoiseLayers", "gradient_noise", "value_noise"]

#: Points per block of the lattice noises (their temporaries stay in the CPU cache).
_NOISE_BLOCK = 16384
#: Perlin's 12 gradient directions (the cube's edge midpoints).
_GRADIENTS = np.array([[1, 1, 0], [-1, 1, 0], [1, -1, 0], [-1, -1, 0], [1, 0, 1], [-1, 0, 1],
                       [1, 0, -1], [-1, 0, -1], [0, 1, 1], [0, -1, 1], [0, 1, -1], [0, -1, -1]], np.float32).T.copy()  # (3, 12)


def value_noise(position_mm: np.ndarray, cell_mm: float, seed: int = 0) -> np.ndarray:
    """3-D value noise (trilinear interpolation of hashed lattice values in [−1, 1], smoothstep
    weights) at (N, 3) points in mm on a lattice of ``cell_mm``: (N,) float32. A function of
    the surface position, so it is continuous across UV seams."""
    return _lattice_noise(position_mm, cell_mm, (seed,), gradient=False)[:, 0]


def gradient_noise(position_mm: np.ndarray, cell_mm: float, seed: int | tuple[int, ...] = 0) -> np.ndarray:
    """3-D gradient (Perlin) noise at (N, 3) points in mm on a lattice of ``cell_mm``: (N,)
    float32, 0 at the lattice points, with most of its power at wavelengths of one to four cells
    (on a plane through it ~86 %, where value noise has ~30 % beyond: octaves of it are
    band-limited without any filtering), isotropic on the surface and continuous across UV seams.
    A tuple of seeds gives (N, len(seed)), one independent noise per seed (each the same as for
    that seed alone; the lattice's coordinates and weights are computed once)."""
    if isinstance(seed, tuple):
        return _lattice_noise(position_mm, cell_mm, seed, gradient=True)
    return _lattice_noise(position_mm, cell_mm, (seed,), gradient=True)[:, 0]


def _lattice_noise(position_mm: np.ndarray, cell_mm: float, seeds: tuple[int, ...], gradient: bool) -> np.ndarray:
    """(N, len(seeds)) float32: :func:`value_noise` or :func:`gradient_noise` for each seed."""
    g = position_mm.astype(np.float32) / np.float32(cell_mm)
    out = np.empty((len(g), len(seeds)), np.float32)
    for start in range(0, len(g), _NOISE_BLOCK):
        out[start:start + _NOISE_BLOCK] = _lattice_noise_block(g[start:start + _NOISE_BLOCK], seeds, gradient)
    return out


def _lattice_noise_block(g: np.ndarray, seeds: tuple[int, ...], gradient: bool) -> np.ndarray:
    """(n, len(seeds)): :func:`value_noise` or :func:`gradient_noise` of (n, 3) float32 lattice coordinates."""
    base = np.floor(g)
    f = g - base
    fade = f * f * f * (f * (6 * f - 15) + 10) if gradient else f * f * (3 - 2 * f)  # Perlin's quintic; smoothstep
    base = base.astype(np.int32)
    # per axis, the lattice point's hash term (int32, wrapping) and trilinear weight at offsets 0 and 1
    terms = [(b * k, (b + 1) * k) for b, k in zip(base.T, (73856093, 19349663, 83492791))]
    weights = [(1 - fade[:, axis], fade[:, axis]) for axis in range(3)]
    offsets = [(f[:, axis], f[:, axis] - 1) for axis in range(3)]  # the offset from the corner at 0 and 1
    out = np.zeros((len(g), len(seeds)), np.float32)
    for corner in range(8):
        o = ((corner >> 2) & 1, (corner >> 1) & 1, corner & 1)
        weight = weights[0][o[0]] * weights[1][o[1]] * weights[2][o[2]]
        lattice = terms[0][o[0]] ^ terms[1][o[1]] ^ terms[2][o[2]]
        for i, seed in enumerate(seeds):
            # integer hash of the lattice point (a xorshift-multiply mix)
            h = lattice ^ (seed * 2654435)
            h = (h ^ (h >> 13)) * 1274126177
            h = h ^ (h >> 16)
            if gradient:  # the corner's gradient · the offset from the corner
                pick = ((h & 0xFFFF) * 12) >> 16
                value = _GRADIENTS[0][pick] * offsets[0][o[0]] + _GRADIENTS[1][pick] * offsets[1][o[1]] + _GRADIENTS[2][pick] * offsets[2][o[2]]
            else:  # the corner's value in [−1, 1]
                value = (h & 0xFFFF).astype(np.float32) * np.float32(2.0 / 65535.0) - 1.0
            out[:, i] += weight * value
    return out


def band_noise(log_rgb: np.ndarray, source: np.ndarray, need: np.ndarray, position_mm: np.ndarray, cover: np.ndarray,
               outside: np.ndarray, finest: float, coarsest: float, texel_mm: float, strength: float = 1.0,
               whole_below: float = 0.0, present: np.ndarray | None = None, seed: int = 0, *,
               settings: DefaultSettings = DEFAULT_SETTINGS) -> np.ndarray:
    """Colour noise (S, S, 3) float32 over ``need`` (S, S) bool with ``strength`` × the octave
    statistics of ``log_rgb`` (S, S, 3) on ``source`` (S, S) bool (the whole statistics in the
    octaves whose finer σ is below ``whole_below`` texels): for each octave of Gaussian σ
    from ``finest`` to ``coarsest`` texels (differences of Gaussians), the 3 × 3 covariance over
    the source's places whose local energy in that octave is at most ``settings.quilt_energy_cap`` ×
    the median place's (the skin's mottling, not a fold, a shadow's edge or a hairline). The noise
    is a sum of independent layers, one per octave: 3-D gradient noise of the surface position
    ``position_mm`` (S, S, 3) in mm on ``cover`` (S, S) bool (:func:`gradient_noise`, a lattice
    of ``settings.noise_cell_per_sigma`` × σ × ``texel_mm``: band-limited by itself, so isotropic on the
    surface and continuous across UV seams, where a UV-space filter would be neither), coloured
    with its octave's covariance at the power that makes the octaves of the sum, measured as the
    source's were, closest to the source's (the layers' spectra overlap: non-negative least
    squares), each faded in over 2σ texels of ``outside`` (S, S), the distance in texels from the
    seen skin, whose octave the fill's base still holds there. Computed on a grid coarser by the
    power of two that leaves ``finest`` ≥ 2 of its texels (each layer on one as coarse as its
    lattice allows), then upsampled bilinearly. ``present`` (S, S, 3), detail already on ``need``
    (the quilted blocks), counts towards each octave: its covariance there is subtracted from the
    wanted one (the nearest covariance where that leaves a negative part), so the noise adds what
    it lacks. 0 outside ``need`` and where ``source`` has fewer than 100 texels; deterministic for
    a given ``seed``. (By hand: no library synthesises noise with a given colour covariance per
    octave on a surface.) In two halves: :func:`noise_layers` (all but ``present``), then
    :func:`coloured_noise`."""
    layers = noise_layers(log_rgb, source, need, position_mm, cover, outside, finest, coarsest, texel_mm, strength, whole_below,
                          seed, settings=settings)
    return coloured_noise(layers, present, log_rgb.shape)


@dataclass(frozen=True)
class NoiseLayers:
    """What :func:`band_noise` makes before the detail already on ``need`` is known
    (:func:`noise_layers`): the grid (``factor`` coarser than the map, ``small`` its (width,
    height)), ``need`` (S, S) bool, the distance ``outside_small`` from the seen skin
    in grid texels, the octaves' ``sigmas`` (grid texels), each octave's wanted colour covariance
    ``target`` (count, 3, 3), the unit-variance noise ``layers`` (count of (h, w, 3) float32) and
    their octaves' overlap ``leak`` (count, count)."""

    factor: int
    small: tuple[int, int]
    need: np.ndarray
    outside_small: np.ndarray
    sigmas: list[float]
    target: np.ndarray
    layers: list[np.ndarray]
    leak: np.ndarray


def _octaves(image: np.ndarray, weight: np.ndarray, sigmas: list[float]) -> list[np.ndarray]:
    """``image``'s differences of Gaussians (masked by ``weight``) between consecutive ``sigmas``."""
    blurred = [masked_blur(image, weight, s) for s in sigmas]
    return [blurred[k] - blurred[k + 1] for k in range(len(sigmas) - 1)]


def noise_layers(log_rgb: np.ndarray, source: np.ndarray, need: np.ndarray, position_mm: np.ndarray, cover: np.ndarray,
                 outside: np.ndarray, finest: float, coarsest: float, texel_mm: float, strength: float = 1.0,
                 whole_below: float = 0.0, seed: int = 0, *, settings: DefaultSettings = DEFAULT_SETTINGS) -> NoiseLayers | None:
    """The first half of :func:`band_noise` (its arguments but ``present``): the octaves' wanted
    covariances and the noise layers, which do not depend on the detail already present (the
    fill makes them while it quilts that detail); None where it adds nothing (too little source
    or nothing to fill)."""
    size = log_rgb.shape[0]
    if source.sum() < 100 or not need.any():
        return None
    factor = 1
    while finest / (2 * factor) >= 2.0 and size // (2 * factor) >= 64:
        factor *= 2
    small = (size // factor, size // factor)

    log_small, source_w = area_mean(log_rgb.astype(np.float32), source, small)
    position, cover_w = area_mean(position_mm.astype(np.float32), cover, small)
    need_small = cv2.resize(need.astype(np.float32), small, interpolation=cv2.INTER_AREA) > 0.5
    outside_small = cv2.resize(outside.astype(np.float32), small, interpolation=cv2.INTER_AREA) / factor
    solid = source_w > 0.99
    if solid.sum() < 100 or not need_small.any():
        return None
    sigmas = [finest / factor]
    while sigmas[-1] < coarsest / factor * (1 - 1e-6):
        sigmas.append(min(2.0 * sigmas[-1], coarsest / factor))
    count = len(sigmas) - 1

    wanted = np.empty((count, 3, 3))  # each octave's covariance over the source's places that are not busy
    for k, band in enumerate(_octaves(log_small, source_w, sigmas)):
        local = masked_blur((band * band).sum(-1), solid, 2.0 * sigmas[k + 1])
        calm = solid & (local <= settings.quilt_energy_cap * np.median(local[solid]))
        wanted[k] = np.cov(band[calm].astype(np.float64).T)
    target = np.where(np.array(sigmas[:-1])[:, None, None] * factor < whole_below, 1.0, strength) * wanted
    # one independent noise layer per octave (3 channels each), unit variance over ``need``
    area = cover_w > 0.5
    layers = []
    for j in range(count):  # gradient noise peaking at the octave's wavelength (~6.5σ), on a grid as coarse as it allows
        cell = settings.noise_cell_per_sigma * sigmas[j]  # in texels of the small grid
        step = 1
        while cell / (2 * step) >= 4.0 and small[0] // (2 * step) >= 32:
            step *= 2
        grid = (small[0] // step, small[1] // step)
        points, covered = (position, cover_w) if step == 1 else area_mean(position, cover_w, grid)
        flat = np.flatnonzero((covered > 0.25).ravel())
        layer = np.zeros((*grid, 3), np.float32)
        layer.reshape(-1, 3)[flat] = gradient_noise(points.reshape(-1, 3)[flat], cell * factor * texel_mm, seed=(seed + 3 * j, seed + 3 * j + 1, seed + 3 * j + 2))
        if step > 1:
            layer = cv2.resize(layer, small, interpolation=cv2.INTER_LINEAR)
        layer = np.where(area[..., None], layer, 0.0)
        layers.append(layer / np.maximum(layer[need_small].std(0), 1e-12))
    # the spectra overlap, so octave k measured on layer j holds a part V_kj of its variance
    firsts = np.stack([layer[..., 0] for layer in layers], axis=-1)  # one channel of each layer (all three alike)
    measured = _octaves(firsts, area, sigmas)
    leak = np.array([[float(np.var(measured[k][..., j][need_small])) for j in range(count)] for k in range(count)])
    return NoiseLayers(factor, small, need, outside_small, sigmas, target, layers, leak)


def coloured_noise(layers: NoiseLayers | None, present: np.ndarray | None, shape: tuple[int, ...]) -> np.ndarray:
    """The second half of :func:`band_noise`: its (S, S, 3) float32 noise of shape ``shape`` from
    the ``layers`` of :func:`noise_layers` (None: zeros), ``present`` (S, S, 3) the detail already
    on ``need`` (None: none)."""
    out = np.zeros(shape, np.float32)
    if layers is None:
        return out
    factor, small, need, sigmas = layers.factor, layers.small, layers.need, layers.sigmas
    target = layers.target.copy()
    if present is not None:  # the detail already there counts towards each octave: the noise adds what it lacks
        have, have_w = area_mean(present.astype(np.float32), need, small)
        inside = have_w > 0.99
        if inside.sum() >= 100:
            for k, band in enumerate(_octaves(have, have_w, sigmas)):
                target[k] -= np.cov(band[inside].astype(np.float64).T)
            values, vectors = np.linalg.eigh(target)  # the nearest covariances (negative parts: more than the source's)
            target = (vectors * np.clip(values, 0.0, None)[:, None, :]) @ vectors.transpose(0, 2, 1)
    # layer j takes octave j's colour covariance at a power t_j with Σ_j V_kj t_j ≈ octave k's
    # variance (relative least squares, t ≥ 0: a steep spectrum cannot be met exactly)
    variance = np.trace(target, axis1=1, axis2=2)
    if variance.max() <= 1e-12:  # flat seen skin, or all its octaves already there: nothing to give
        return out
    weight = 1.0 / np.maximum(variance, 1e-3 * variance.max())
    scale = nonnegative_least_squares(layers.leak * weight[:, None], variance * weight)
    power = (scale / np.maximum(variance, 1e-12))[:, None, None] * target  # t_j × the octave's covariance of trace 1
    total = np.zeros((*layers.outside_small.shape, 3), np.float32)
    for j, (layer, p) in enumerate(zip(layers.layers, power)):
        values, vectors = np.linalg.eigh((p + p.T) / 2)
        root = (vectors * np.sqrt(np.clip(values, 0.0, None))).astype(np.float32)  # root @ root.T = p (singular for a greyscale photo)
        ramp = smoothstep(layers.outside_small / (2.0 * sigmas[j]))[..., None]  # near the seen skin the fill's base still holds the octave
        total += ramp * (layer @ root.T)
    if factor > 1:
        total = cv2.resize(total, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    return np.where(need[..., None], total, 0.0).astype(np.float32)
