"""The default texture backend on a synthetic UV context: a hemisphere seen from the front."""

from dataclasses import FrozenInstanceError, replace

import cv2
import numpy as np
import pytest
import torch

from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear
from facegeo.lighting import sh_irradiance
from facegeo.texturing.backend import TextureBackend, TextureContext
from facegeo.texturing.default import DEFAULT_SETTINGS, DefaultBackend, DefaultSettings
from facegeo.texturing.default.clipping import restore_clipped
from facegeo.texturing.default.highlights import white_share
from facegeo.texturing.default.least_squares import nonnegative_least_squares
from facegeo.texturing.default.noise import band_noise, coloured_noise, gradient_noise, value_noise
from facegeo.texturing.default.quilting import quilted_detail
from facegeo.texturing.default.reliability import shading_confidence
from facegeo.texturing.default.sheen import without_sun_sheen
from facegeo.texturing.image_filters import masked_blur, pad_outside

#: The settings for a photo without specular reflection (the synthetic photos here, diffuse only).
DIFFUSE = replace(DEFAULT_SETTINGS, skin_albedo=None)


def psnr(a, b, mask):
    mse = float(np.mean((a[mask] - b[mask]) ** 2))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def hemisphere_context(size=128, gamma=None):
    """UV square = orthographic view of a unit hemisphere (radius 80 mm) facing +Z; the mirror of
    column c is column S−1−c; regions split it into a 'forehead' top and 'cheeks' bottom."""
    r = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(r, -r)
    inside = x**2 + y**2 < 0.95**2
    z = np.sqrt(np.clip(1 - x**2 - y**2, 0, 1))
    normals = np.where(inside[..., None], np.stack([x, y, z], -1), 0).astype(np.float32)
    mirror = np.stack(np.meshgrid(np.arange(size), np.arange(size)[::-1], indexing="ij"), -1)[..., ::-1].copy()
    mirror[..., 0] = np.arange(size)[:, None]
    mirror[..., 1] = size - 1 - np.arange(size)[None, :]
    mirror = np.where(inside[..., None], mirror, -1).astype(np.int32)
    texel = np.full((size, size, 2), 160.0 / size, np.float32) / np.maximum(z, 0.2)[..., None]
    gamma = np.zeros((3, 9), np.float32) if gamma is None else gamma
    if gamma is None or not gamma.any():
        gamma[:, 0] = 1.0
    return TextureContext(
        coverage=inside,
        position=(80 * normals).astype(np.float32),
        normal_camera=normals,
        texel_size_mm=texel,
        gamma=gamma,
        mean_texture=np.full((size, size, 3), 0.5, np.float32),
        mirror=mirror,
        regions={"forehead": (y > 0.3).astype(np.float32) * inside, "cheeks": (y < -0.2).astype(np.float32) * inside},
        skin=inside.astype(np.float32),
    )


def skin_albedo(size, seed=0):
    """A left/right symmetric, skin-coloured albedo with mid-frequency blotches (sRGB)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(size, size)).astype(np.float32)
    noise = masked_blur(noise, np.ones((size, size)), 3.0)
    noise = 0.5 * (noise + noise[:, ::-1])
    base = np.array([0.78, 0.58, 0.48], np.float32)
    return np.clip(base * (1 + 0.6 * noise[..., None]), 0, 1)


def test_protocol_is_satisfied():
    assert isinstance(DefaultBackend(), TextureBackend)


def test_homogenise_removes_known_white_sh_shading_and_keeps_chroma():
    gamma = np.zeros((3, 9), np.float32)
    gamma[:, 0] = 0.9
    gamma[:, 2] = 0.2  # frontal light
    gamma[:, 3] = -0.35  # from the side: clearly directional (a weaker one is left in, directional_range)
    gamma[:, 1] = 0.1
    ctx = hemisphere_context(128)
    albedo = skin_albedo(128)
    e = sh_irradiance(torch.from_numpy(ctx.normal_camera), torch.from_numpy(gamma)).numpy()
    shaded = linear_to_srgb(srgb_to_linear(albedo) * e)
    backend = DefaultBackend(settings=DIFFUSE)  # a diffuse-only photo: no sheen to remove
    out = backend.homogenise(shaded, ctx)
    # compare up to the global scale the homogenised texture is defined to
    lin_out, lin_ref = srgb_to_linear(out), srgb_to_linear(albedo)
    m = ctx.coverage & (ctx.normal_camera[..., 2] > 0.3)  # grazing texels have bounded gains
    scale = (lin_ref[m] * lin_out[m]).sum() / (lin_out[m] ** 2).sum()
    assert psnr(linear_to_srgb(lin_out * scale), albedo, m) > 32.0
    assert psnr(shaded, albedo, m) < 25.0  # the shading really was there
    assert backend.report["homogenise"]["remaining_fraction"] < 0.05
    # white light: the shading changes luminance only, and the light's colour is one gain per
    # channel for the whole map: each texel's chroma moves by the same amount
    lin_in = srgb_to_linear(shaded)
    shift = np.log(lin_out[m][:, [0, 2]] / lin_out[m][:, 1:2]) - np.log(lin_in[m][:, [0, 2]] / lin_in[m][:, 1:2])
    assert np.abs(shift - np.median(shift, axis=0)).max() < 2e-3


def test_warm_light_is_removed_with_the_sclera_as_white_reference():
    """Skin under a warm light (×(1, 0.78, 0.55) in linear RGB) with the photo's sclera as white
    reference: the albedo's chroma is back near the skin's own, far nearer than the photo's;
    under white light the chroma barely moves."""
    from facegeo.texturing.illuminant import SCLERA_CHROMA, chroma

    ctx = hemisphere_context(64)
    skin = srgb_to_linear(np.array([0.80, 0.60, 0.50], np.float32))
    sclera = np.exp(np.array([SCLERA_CHROMA[0], 0.0, SCLERA_CHROMA[1]]))
    results = {}
    for name, light in (("warm", np.array([1.0, 0.78, 0.55], np.float32)), ("white", np.ones(3, np.float32))):
        shaded = np.broadcast_to(linear_to_srgb(skin * light), (64, 64, 3)).astype(np.float32)
        ctx.white_reference = sclera * light
        out = DefaultBackend(settings=DIFFUSE).homogenise(shaded, ctx)
        results[name] = np.median(chroma(srgb_to_linear(out)[ctx.coverage]), axis=0)
    truth = chroma(skin)
    photo_error = np.linalg.norm(chroma(skin * np.array([1.0, 0.78, 0.55])) - truth)
    assert np.linalg.norm(results["warm"] - truth) < 0.05 * photo_error  # (a soft threshold kept back ~0.25)
    assert np.linalg.norm(results["white"] - truth) < 0.05


def test_greyscale_photo_gets_an_invented_skin_chroma_and_a_note():
    ctx = hemisphere_context(64)
    grey = np.full((64, 64, 3), 0.55, np.float32)
    backend = DefaultBackend()
    full = backend.inpaint(grey, ctx.coverage.astype(np.float32), ctx)
    out = backend.homogenise(full, ctx)
    lin = srgb_to_linear(out[ctx.coverage])
    assert np.all(lin[:, 0] > 1.2 * lin[:, 1]) and np.all(lin[:, 1] > lin[:, 2])  # skin: R > G > B
    assert backend.report["illuminant"]["greyscale"] and any("greyscale" in n for n in backend.report["notes"])


def test_even_light_leaves_albedo_that_correlates_with_the_normals_alone():
    """Under an even light (constant shading) an albedo darker towards one side (a beard zone)
    correlates with the normals: an SH fit finds a 'light' there, but it is too weakly directional
    to be divided out (directional_range): the albedo keeps its gradient."""
    ctx = hemisphere_context(128)
    x = ctx.normal_camera[..., 0]
    albedo = linear_to_srgb(srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * (1.0 - 0.12 * x)[..., None])
    backend = DefaultBackend()
    out = srgb_to_linear(backend.homogenise(albedo, ctx))
    lum_in, lum_out = srgb_to_linear(albedo).mean(-1), out.mean(-1)
    m = ctx.coverage & (ctx.normal_camera[..., 2] > 0.3)
    left, right = m & (x < -0.4), m & (x > 0.4)
    ratio_in = lum_in[left].mean() / lum_in[right].mean()
    assert backend.report["analyse"]["delighting_strength"] < 0.5
    assert abs(lum_out[left].mean() / lum_out[right].mean() / ratio_in - 1) < 0.05


def test_highlights_are_found_removed_and_make_the_skin_glossier():
    ctx = hemisphere_context(128)
    albedo = np.broadcast_to(np.float32([0.75, 0.55, 0.45]), (128, 128, 3)).copy()
    lin = srgb_to_linear(albedo)
    r2 = ((np.arange(128)[:, None] - 40) ** 2 + (np.arange(128)[None, :] - 50) ** 2).astype(np.float32)
    spot = 0.5 * np.exp(-r2 / (2 * 1.5**2))  # a white specular highlight, σ 1.5 texels (~4 mm at 1K)
    photo = linear_to_srgb(lin + spot[..., None])
    vis = ctx.coverage.astype(np.float32)
    vis[:, 64:] = 0.0  # the mirror side of the spot is hidden: the fill must come from around it
    backend = DefaultBackend()
    an = backend.analyse(photo, vis, ctx)
    assert an.highlight[40, 50] > 0.9 and an.highlight[100, 30] == 0.0
    full = backend.inpaint(photo, vis, ctx)
    out = backend.homogenise(full, ctx)
    assert np.abs(photo[40, 50] - albedo[40, 50]).max() > 0.2
    level = backend.report["albedo_level"]["k"]  # the albedo's level is the skin prior's, not the photo's
    assert np.abs(out[40, 50] - linear_to_srgb(lin[40, 50] * level)).max() < 0.04  # the highlight is gone
    maps = backend.materials(out, ctx, maps={"roughness", "specular"})
    assert maps["specular"][40, 50] > maps["specular"][40, 20] + 0.05
    assert maps["roughness"][40, 50] < maps["roughness"][40, 20] - 0.05


def test_seen_skin_far_from_the_reliable_skin_is_judged_against_its_own_neighbourhood():
    """Reliable skin only in the middle of the hemisphere: the rim is beyond the highlight
    neighbourhood's reach (~3σ, 8 texels at S = 128). Judged against that skin, its mean there
    was 0 and the whole rim passed for a highlight (filled, weight 0); against the seen texels
    around it, only a white spot on it is one."""
    size = 128
    ctx = hemisphere_context(size)
    r = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(r, -r)
    ctx.skin[...] = (np.hypot(x, y) < 0.35) * ctx.coverage
    lin = srgb_to_linear(np.broadcast_to(np.float32([0.75, 0.55, 0.45]), (size, size, 3)))
    rows, cols = np.arange(size)[:, None], np.arange(size)[None, :]
    spot = 0.5 * np.exp(-((rows - 64) ** 2 + (cols - 12) ** 2) / (2 * 1.5**2))  # on the rim, row 64, column 12
    an = DefaultBackend().analyse(linear_to_srgb(lin + spot[..., None]), ctx.coverage.astype(np.float32), ctx)
    rim = ctx.coverage & (np.hypot(x, y) > 0.6) & (np.hypot(rows - 64, cols - 12) > 8)
    assert an.highlight[rim].max() == 0.0 and an.weight[rim].min() > 0.99
    assert an.highlight[64, 12] > 0.9


def test_white_share_tells_a_white_specular_from_brighter_skin():
    """The dichromatic model: skin + white is all white excess, brighter skin none, and a mix its share."""
    skin = srgb_to_linear(np.float32([0.75, 0.55, 0.45]))
    reference = np.broadcast_to(skin, (1, 3, 3))
    texture = np.stack([skin + 0.2, 1.5 * skin, 1.2 * skin + 0.1])[None]
    share = white_share(texture.astype(np.float32), reference.astype(np.float32))
    excess = luminance(texture[0]) - luminance(skin)
    np.testing.assert_allclose(share[0], [1.0, 0.0, 0.1 / excess[2]], atol=1e-4)
    assert white_share(np.float32([[0.5 * skin]]), np.float32([[skin]]))[0, 0] == 0.0  # darker: no excess


def test_skin_between_stubble_hairs_is_no_highlight_but_a_shine_and_a_white_glint_are():
    """Stubble: 2 × 2-texel dark hairs on a checkerboard over the lower half (texel ~0.4 mm). The skin
    between them is ~1.8 × the neighbourhood's mean, which the hairs drag down, and no whiter than
    it: it was all highlight (filled, smooth holes in the stubble); now none of it is. A shine
    (2.5 × over σ = 2.5 mm) and a white glint (σ = 1 texel) on the forehead still are."""
    size = 512
    ctx = hemisphere_context(size)
    r = (np.arange(size) + 0.5) / size * 2 - 1
    x, y = np.meshgrid(r, -r)
    rows, cols = np.mgrid[0:size, 0:size]
    lin = np.broadcast_to(srgb_to_linear(np.float32([0.75, 0.55, 0.45])), (size, size, 3)).copy()
    stubble = (y < -0.1) & (np.abs(x) < 0.5) & ((rows // 2 + cols // 2) % 2 == 0)
    lin[stubble] = srgb_to_linear(np.float32([0.25, 0.17, 0.12]))
    glint = 0.6 * np.exp(-((rows - 120) ** 2 + (cols - 200) ** 2) / (2 * 1.0**2))
    shine = np.exp(-((rows - 120) ** 2 + (cols - 330) ** 2) / (2 * 6.0**2))
    lin = (lin + glint[..., None]) * (1 + 1.5 * shine)[..., None]
    an = DefaultBackend().analyse(linear_to_srgb(np.clip(lin, 0, 1)), ctx.coverage.astype(np.float32), ctx)
    between = (y < -0.15) & (np.abs(x) < 0.45) & ~stubble & ctx.coverage
    assert an.highlight[between].max() == 0.0 and an.weight[between].min() > 0.99
    assert an.highlight[120, 200] > 0.9 and an.highlight[120, 330] > 0.9


def test_gains_are_bounded_and_smaller_at_grazing_angles():
    gamma = np.zeros((3, 9), np.float32)
    gamma[:, 0], gamma[:, 3] = 0.6, -0.8  # strong side light: half the sphere nearly black
    ctx = hemisphere_context(128)
    e = sh_irradiance(torch.from_numpy(ctx.normal_camera), torch.from_numpy(gamma)).numpy()
    shaded = linear_to_srgb(srgb_to_linear(skin_albedo(128)) * np.maximum(e, 0.02))
    an = DefaultBackend().analyse(shaded, ctx.coverage.astype(np.float32), ctx)
    gain = 1.0 / an.shading[ctx.coverage]
    max_gain, grazing_gain = DEFAULT_SETTINGS.max_gain, DEFAULT_SETTINGS.grazing_gain
    assert gain.max() <= max_gain + 1e-5 and gain.min() >= 1.0 / max_gain - 1e-5
    bound = grazing_gain + (max_gain - grazing_gain) * np.clip(ctx.normal_camera[..., 2] / 0.5, 0, 1)
    assert np.all(1.0 / an.shading[ctx.coverage] <= bound[ctx.coverage] + 1e-5)
    assert np.all(an.shading[ctx.coverage] <= bound[ctx.coverage] + 1e-5)


def test_hidden_side_gets_the_mirrors_fine_detail_in_the_local_tone_without_a_seam():
    """Right part hidden; the seen skin has fine detail (1-texel pores) and a left-to-right tone
    ramp. The fill takes the mirror's fine detail (correlated with the truth there), the tone of
    the seen skin next to it, and no step at the visibility boundary."""
    size = 128
    ctx = hemisphere_context(size)
    rng = np.random.default_rng(1)
    pores = rng.normal(size=(size, size)).astype(np.float32)
    pores = 0.5 * (pores + pores[:, ::-1])  # left/right symmetric
    x = np.linspace(-1, 1, size)[None, :].repeat(size, 0)
    tone = 1.0 + 0.15 * x  # brighter to the right
    truth = np.clip(srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * (tone * np.exp(0.08 * pores))[..., None], 0, 1)
    visible = (x < 0.1).astype(np.float32)
    t_inc = linear_to_srgb(truth) * visible[..., None]
    backend = DefaultBackend()
    out = srgb_to_linear(backend.homogenise(backend.inpaint(t_inc, visible, ctx), ctx))
    lum, lum_true = out.mean(-1), truth.mean(-1)
    hidden = ctx.coverage & (x > 0.3) & (ctx.normal_camera[..., 2] > 0.3)
    fine = lambda a: a - masked_blur(a, ctx.coverage, 2.0)  # noqa: E731
    assert np.corrcoef(fine(lum)[hidden], fine(lum_true)[hidden])[0, 1] > 0.5  # the mirror's detail
    # tone: the boundary's, not the whole seen half's mean (which is darker)
    near = ctx.coverage & (np.abs(x + 0.0) < 0.05)
    far_fill = ctx.coverage & (x > 0.2) & (x < 0.3)
    assert abs(np.median(lum[far_fill]) / np.median(lum[near]) - 1) < 0.05
    # no seam: the smoothed luminance's steps across the boundary are like those elsewhere
    smooth = masked_blur(lum, ctx.coverage, 2.0)
    step = np.abs(np.diff(smooth, axis=1))
    inside = ctx.coverage[:, 1:] & ctx.coverage[:, :-1] & (np.abs(ctx.normal_camera[..., 1])[:, 1:] < 0.6)
    at = inside & (np.abs(x[:, 1:] - 0.1) < 0.06)
    elsewhere = inside & (np.abs(x[:, 1:] - 0.1) > 0.2) & (np.abs(x[:, 1:]) < 0.7)
    assert step[at].mean() < 1.5 * step[elsewhere].mean()
    assert np.all(np.isfinite(out)) and out.min() >= 0 and out.max() <= 1


@pytest.mark.parametrize("baked_light", [False, True])
def test_the_hidden_side_takes_the_mirrors_tone_only_where_the_seen_face_is_symmetric(baked_light):
    """A darker (stubbled) jaw on both sides, the right one hidden. Where the skin seen on both
    sides of the mirror line agrees, the hidden jaw takes the mirror's tone (0.70 of the skin
    beside it, as in the truth); where a left-to-right ramp (a light the de-lighting left in)
    makes the seen sides differ, the mirror is not trusted and the hidden jaw takes the tone of
    the seen skin next to it."""
    size = 128
    ctx = hemisphere_context(size)
    x = np.linspace(-1, 1, size)[None, :].repeat(size, 0)
    y = -x.T
    jaw = ((y < -0.35) & (np.abs(x) > 0.35) & (np.abs(x) < 0.8)).astype(np.float32)
    pores = np.random.default_rng(3).normal(size=(size, size)).astype(np.float32)
    pores = 0.5 * (pores + pores[:, ::-1])  # left/right symmetric, as the jaw
    log_tone = -0.36 * masked_blur(jaw, np.ones_like(jaw), 2.0) + 0.05 * pores + (1.0 * x if baked_light else 0.0)
    truth = srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * np.exp(log_tone)[..., None]
    visible = (x < 0.3).astype(np.float32)
    backend = DefaultBackend(settings=DIFFUSE)
    out = srgb_to_linear(backend.homogenise(backend.inpaint(linear_to_srgb(np.clip(truth, 0, 1)) * visible[..., None], visible, ctx), ctx))
    lum = luminance(out)
    report = backend.report["inpaint"]
    hidden_jaw = ctx.coverage & (y < -0.45) & (y > -0.6) & (x > 0.45) & (x < 0.6)
    beside = ctx.coverage & (y > -0.15) & (y < 0.1) & (x > 0.45) & (x < 0.6)  # hidden too, no stubble
    ratio = np.median(lum[hidden_jaw]) / np.median(lum[beside])
    if baked_light:
        assert report["mirror_asymmetry"] > 0.15 and report["mirror_tone"] == 0.0
        assert ratio > 0.9  # not copied: the left side's darker tone is the ramp's as much as the jaw's
    else:
        assert report["mirror_asymmetry"] < 0.03 and report["mirror_tone"] == 1.0
        # the mirror's tone: the seen jaw's (0.78 of the skin beside it after de-lighting, which takes
        # a little of the dark lower half for shading; the truth 0.70), not the skin next to it (0.99)
        seen_ratio = np.median(lum[hidden_jaw[:, ::-1]]) / np.median(lum[beside[:, ::-1]])
        assert ratio < 0.85 and abs(ratio - seen_ratio) < 0.03
    assert np.all(np.isfinite(out))


def test_reliability_fades_towards_silhouettes_and_occluders():
    ctx = hemisphere_context(128)
    weight = ctx.coverage.astype(np.float32)
    weight[60:68, 60:68] = 0.0  # an occluder in the middle
    r = DefaultBackend().reliability(weight, ctx)
    assert r[64, 64] == 0.0 and r[64, 30] > 0.9  # on the occluder / clear, facing skin
    assert 0 < r[64, 68] < r[64, 69] < r[64, 90] == 1.0  # rises away from the occluder (over edge_mm)
    assert r[64, 2] < 0.05 or not ctx.coverage[64, 2]  # grazing at the rim


@pytest.mark.parametrize("fringe_mm", [DEFAULT_SETTINGS.fringe_mm, 0.0])
def test_an_occluders_fringe_is_filled_and_the_same_colour_inside_the_face_kept(fringe_mm):
    """Hair above a line is masked, but the mask lets its last two texels of strands (dark,
    bluish grey) through; the same colour also marks the middle of the face. The fringe is filled
    with the skin next to it; the mark far from the mask's edge is the face's own and stays. With
    fringe_mm = 0 the strands stay dark (the edge's reliability ramp alone does not remove them)."""
    size = 128
    ctx = hemisphere_context(size)
    rng = np.random.default_rng(3)
    skin = srgb_to_linear(np.float32([0.78, 0.58, 0.48]))
    truth = skin * np.exp(0.03 * rng.normal(size=(size, size, 1))).astype(np.float32)
    row = np.arange(size)[:, None].repeat(size, 1)
    seen = (row >= 40) & ctx.coverage
    strands = seen & (row < 42)
    mark = (np.abs(row - 80) < 3) & (np.abs(np.arange(size)[None, :] - 64) < 3)
    hair = srgb_to_linear(np.float32([0.16, 0.17, 0.2]))
    photo = np.where((strands | mark)[..., None], hair, truth)
    backend = DefaultBackend(settings=replace(DEFAULT_SETTINGS, fringe_mm=fringe_mm))
    out = srgb_to_linear(backend.homogenise(backend.inpaint(linear_to_srgb(photo) * seen[..., None], seen.astype(np.float32), ctx), ctx))
    lum = luminance(out)
    around = ctx.coverage & (row >= 46) & (row < 56) & (np.abs(np.arange(size)[None, :] - 64) < 30)
    band = strands & (np.abs(np.arange(size)[None, :] - 64) < 30)
    ratio = float(np.median(lum[band]) / np.median(lum[around]))
    if fringe_mm > 0:
        assert ratio > 0.9  # filled with the skin below it
        assert backend.report["analyse"]["occluder_fringe_fraction_of_seen_skin"] > 0
    else:
        assert ratio < 0.75
    assert np.median(lum[mark]) < 0.5 * np.median(lum[around])  # the face's own mark is kept


def test_in_a_greyscale_photo_dark_hair_anywhere_on_the_face_is_filled():
    """The same strands and mark in a greyscale photo: without chroma the photo's skin mask lets
    a sideburn or a hairline through anywhere (the cameraman's), so a de-lit colour beyond the
    seen skin's is taken out wherever it is seen, the mark in the middle of the face included."""
    size = 128
    ctx = hemisphere_context(size)
    rng = np.random.default_rng(3)
    truth = np.float32(0.3) * np.exp(0.03 * rng.normal(size=(size, size, 1))).astype(np.float32).repeat(3, axis=-1)
    row = np.arange(size)[:, None].repeat(size, 1)
    column = np.arange(size)[None, :].repeat(size, 0)
    seen = (row >= 40) & ctx.coverage
    mark = (np.abs(row - 80) < 3) & (np.abs(column - 64) < 3)
    photo = np.where(mark[..., None], np.float32(0.025), truth)
    backend = DefaultBackend()
    out = srgb_to_linear(backend.homogenise(backend.inpaint(linear_to_srgb(photo) * seen[..., None], seen.astype(np.float32), ctx), ctx))
    lum = luminance(out)
    around = ctx.coverage & (np.abs(row - 80) < 10) & (np.abs(column - 64) < 10) & ~mark
    assert backend.report["illuminant"]["greyscale"]
    assert np.median(lum[mark]) > 0.9 * np.median(lum[around])


def test_inpaint_with_nothing_visible_falls_back_to_the_model_colour():
    ctx = hemisphere_context(64)
    full = DefaultBackend().inpaint(np.zeros((64, 64, 3), np.float32), np.zeros((64, 64), np.float32), ctx)
    assert np.all(np.isfinite(full))
    np.testing.assert_allclose(np.median(full[ctx.coverage], axis=0), 0.5, atol=0.02)


def test_materials_only_what_is_asked_and_physically_sensible():
    ctx = hemisphere_context(128)
    albedo = np.full((128, 128, 3), 0.6, np.float32)
    albedo[63:65, 63:65] = 0.2  # a dark pore-like pit in the middle
    backend = DefaultBackend()
    assert set(backend.materials(albedo, ctx, maps={"albedo"})) == {"albedo"}
    maps = backend.materials(albedo, ctx)
    assert set(maps) == {"albedo", "normal", "roughness", "specular", "displacement"}
    d, n = maps["displacement"], maps["normal"]
    assert d[64, 64] < -0.1 and abs(d[40, 40]) < 1e-3  # dark = deeper, flat elsewhere
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    # left of the pit the surface goes down towards +u: the normal tilts towards +u (x > 0)
    assert n[64, 62, 0] > 0.05 and n[64, 65, 0] < -0.05
    assert 0 <= maps["roughness"].min() and maps["roughness"].max() <= 1
    assert maps["specular"][20, 64] > maps["specular"][110, 64]  # forehead glossier than cheeks
    with pytest.raises(ValueError):
        backend.materials(albedo, ctx, maps={"sheen"})


def test_pad_outside_and_blur_helpers():
    inside = np.zeros((8, 8), bool)
    inside[2:4, 2:4] = True
    image = np.where(inside, 1.0, 0.0).astype(np.float32)
    padded = pad_outside(image, inside)
    assert padded.min() == 1.0
    wide = np.zeros((64, 64), bool)
    wide[20:40, 20:40] = True
    ramp = np.where(wide, np.arange(64, dtype=np.float32)[None, :], 0.0)
    padded = pad_outside(ramp, wide, width=3)
    assert padded[30, 42] == 39.0 and padded[30, 17] == 20.0  # the edge colour, 2–3 texels out
    flat = padded[np.hypot(*np.meshgrid(np.arange(64) - 30, np.arange(64) - 30)) > 25]
    assert np.all(flat == flat[0]) and 20.0 < flat[0] < 39.0  # then flat: the median, no streaks
    image = np.zeros((32, 32), np.float32)
    weight = np.zeros((32, 32), np.float32)
    image[:, :16], weight[:, :16] = 2.0, 1.0
    np.testing.assert_allclose(masked_blur(image, weight, 3.0)[:, :20], 2.0, rtol=1e-4)  # only weighted texels count


def test_value_noise_is_bounded_deterministic_and_continuous():
    p = np.random.default_rng(0).uniform(-50, 50, (2000, 3)).astype(np.float32)
    n = value_noise(p, 0.5)
    assert np.abs(n).max() <= 1.0 and n.std() > 0.1
    np.testing.assert_array_equal(n, value_noise(p, 0.5))
    assert np.abs(value_noise(p + 1e-3, 0.5) - n).max() < 0.05  # 1 µm moves it little
    assert np.corrcoef(n, value_noise(p, 0.5, seed=1))[0, 1] < 0.2


def test_gradient_noise_is_zero_on_the_lattice_deterministic_and_band_limited():
    """Perlin noise: 0 at the lattice points, within [−1, 1], deterministic, another seed another
    field, a 1 µm step moves it little; on a plane through it, > 80 % of its power lies between
    wavelengths of one and four cells and < 15 % beyond (value noise: > 25 % beyond)."""
    rng = np.random.default_rng(1)
    p = rng.uniform(-50, 50, (4000, 3)).astype(np.float32)
    n = gradient_noise(p, 2.0)
    assert np.abs(n).max() <= 1.0 and n.std() > 0.15
    np.testing.assert_array_equal(n, gradient_noise(p, 2.0))
    assert abs(np.corrcoef(n, gradient_noise(p, 2.0, seed=1))[0, 1]) < 0.2
    np.testing.assert_array_equal(gradient_noise(p, 2.0, seed=(0, 1)), np.stack([n, gradient_noise(p, 2.0, seed=1)], axis=1))  # seeds at once
    assert np.abs(gradient_noise(np.round(p / 2.0) * 2.0, 2.0)).max() < 1e-6
    assert np.abs(gradient_noise(p + 1e-3, 2.0) - n).max() < 0.01
    # on a tilted plane (a surface through the 3-D field): the power spectrum by wavelength
    size = 512
    yy, xx = np.mgrid[:size, :size].astype(np.float32) * 0.25  # 0.25 mm texels, cells of 2 mm
    rotation = np.linalg.qr(rng.normal(size=(3, 3)))[0].astype(np.float32)
    plane = (np.stack([xx, yy, np.full_like(xx, 0.37)], -1).reshape(-1, 3) @ rotation.T).astype(np.float32)
    f = np.fft.fftfreq(size, 0.25)
    wavelength = 1.0 / np.maximum(np.hypot(*np.meshgrid(f, f)), 1e-9)  # mm

    def shares(noise):
        v = noise(plane, 2.0).reshape(size, size)
        power = np.abs(np.fft.fft2(v - v.mean())) ** 2
        power /= power.sum()
        return power[(wavelength >= 2.0) & (wavelength < 8.0)].sum(), power[wavelength >= 8.0].sum()

    inside, beyond = shares(gradient_noise)
    assert inside > 0.8 and beyond < 0.15  # one to four cells
    assert shares(value_noise)[1] > 0.25  # value noise spreads to long wavelengths


def test_nonnegative_least_squares_agrees_with_scipy():
    """Random small systems, some with a negative unconstrained optimum: the same solution as
    scipy.optimize.nnls (Lawson–Hanson) within 1e-9."""
    from scipy.optimize import nnls

    rng = np.random.default_rng(7)
    for n in (1, 2, 3, 5):
        for _ in range(20):
            a = rng.normal(size=(n + 2, n))
            b = rng.normal(size=n + 2)
            np.testing.assert_allclose(nonnegative_least_squares(a, b), nnls(a, b)[0], atol=1e-9)
    with pytest.raises(ValueError, match="at most 8"):
        nonnegative_least_squares(np.ones((9, 9)), np.ones(9))


def test_band_noise_is_a_function_of_the_surface_point():
    """Two UV halves that map to the same surface points (a UV seam's two sides, stretched alike)
    get the same noise at corresponding texels away from where they meet: the fill's mottling
    has no seam."""
    size = 512
    rng = np.random.default_rng(6)
    ones = np.ones((size, size))
    texture = masked_blur(rng.normal(size=(size, size, 3)).astype(np.float32), ones, 1.0) * 0.1
    half = size // 2
    yy, xx = np.mgrid[:size, :size].astype(np.float32)
    position = np.stack([(xx % half) * 0.4, yy * 0.4, np.zeros_like(xx)], -1)
    source = np.zeros((size, size), bool)
    source[:96] = True
    need = ~source
    far = np.full((size, size), 1e3, np.float32)
    out = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 2.0, 16.0, 0.4)
    left, right = out[160:-16, 16 : half - 16], out[160:-16, half + 16 : -16]
    assert left.std() > 0
    assert np.abs(left - right).max() < 0.05 * left.std()


def _quilting_band(size, channels, sigma, seed):
    """(S, S, C) float32 detail in the band the backend quilts: isotropic noise blurred over
    1 texel less its blur over S/256 texels, scaled to standard deviation ``sigma``."""
    ones = np.ones((size, size))
    noise = masked_blur(np.random.default_rng(seed).normal(size=(size, size, channels)).astype(np.float32), ones, 1.0)
    band = noise - masked_blur(noise, ones, size / 256)
    return (band * (sigma / band.std())).astype(np.float32)


def test_quilted_detail_keeps_the_sources_contrast_and_scale_without_a_block_grid():
    """Blocks of a source detail layer of known statistics (isotropic noise blurred over 1 texel,
    less its blur over S/256 texels: the band the backend quilts; σ 0.05) quilted over the rest of
    the map: the copy has the source's σ and mean gradient (within 10 %), zero mean, no variance
    pattern with the block grid's period, is deterministic and 0 outside ``need``."""
    size = 1024
    texture = _quilting_band(size, 2, 0.05, seed=0)
    source = np.zeros((size, size), bool)
    source[:, : size // 2] = True
    need = ~source
    out = quilted_detail(np.where(source[..., None], texture, 0.0), source, need)
    assert out.shape == texture.shape and out.dtype == np.float32
    assert np.all(out[~need] == 0)
    filled = out[need]
    assert abs(filled.std() / texture[source].std() - 1) < 0.1
    assert abs(filled.mean()) < 0.1 * texture.std()
    gradient = lambda a: np.abs(np.diff(a, axis=1)).mean()  # noqa: E731
    ratio = gradient(out[:, size // 2 + 2 :]) / gradient(texture[:, : size // 2])
    assert 0.9 < ratio < 1.1
    # no grid: the variance by position modulo the block's half is flat
    half = round(DEFAULT_SETTINGS.quilt_block * size / 2)
    region = out[:, size // 2 + 2 * half : size // 2 + 2 * half + 8 * half]
    by_phase = [(region[:, k::half] ** 2).mean() for k in range(half)]
    assert max(by_phase) / min(by_phase) < 1.3
    np.testing.assert_array_equal(out, quilted_detail(np.where(source[..., None], texture, 0.0), source, need))
    assert not np.array_equal(out, quilted_detail(np.where(source[..., None], texture, 0.0), source, need, seed=1))
    # too little source for a whole block: no quilt
    tiny = np.zeros((size, size), bool)
    tiny[:4, :4] = True
    assert quilted_detail(texture, tiny, ~tiny) is None


def test_quilted_detail_leaves_out_blocks_with_a_speck():
    """Pores (σ 0.02) with a few dark specks (−0.5: a mole, a lash) on 1 % of the source: blocks
    holding a speck are busier than quilt_energy_cap × the median block, so no speck is copied."""
    size = 512
    rng = np.random.default_rng(2)
    detail = (0.02 * rng.normal(size=(size, size, 1))).astype(np.float32)
    specks = rng.random((size, size)) < 0.0004  # ~100 specks, each in ~1 % of the blocks' places
    detail[specks] = -0.5
    source = np.zeros((size, size), bool)
    source[:, : size // 2] = True
    out = quilted_detail(detail, source, ~source)
    assert out[~source].min() > -0.15  # a copied speck would be ≲ −0.3 (windowed, normalised)
    assert 0.8 < out[~source].std() / 0.02 < 1.2


def _albedo_with_the_right_hidden(ctx, log_detail):
    """A skin colour × exp(``log_detail``) (S, S) on the hemisphere ``ctx``, the part right of
    x = 0.1 hidden, through the default backend: (the backend, x (S, S), the visibility (S, S),
    the albedo's log-luminance (S, S))."""
    size = ctx.size
    truth = srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * np.exp(log_detail)[..., None]
    x = np.linspace(-1, 1, size)[None, :].repeat(size, 0)
    visible = (x < 0.1).astype(np.float32)
    backend = DefaultBackend()
    out = srgb_to_linear(backend.homogenise(backend.inpaint(linear_to_srgb(truth) * visible[..., None], visible, ctx), ctx))
    return backend, x, visible, np.log(np.maximum(out.mean(-1), 1e-4))


def test_quilted_detail_takes_the_texture_of_the_source_next_to_it():
    """The source's upper half is stubble (3 × the contrast of the lower half's pores): the fill
    beside each half gets that half's contrast (within 25 %). Drawn from anywhere, the blocks
    gave both sides one mix (0.51 and 1.57 of their neighbours'; the busy half's blocks also
    fell under the cap of the whole source's median)."""
    size = 512
    texture = _quilting_band(size, 1, 0.02, seed=4)
    rows = np.arange(size)[:, None].repeat(size, 1)
    stubble = rows < size // 2
    texture[stubble] *= 3.0
    source = np.zeros((size, size), bool)
    source[:, : size // 2] = True
    out = quilted_detail(np.where(source[..., None], texture, 0.0), source, ~source)
    margin = round(DEFAULT_SETTINGS.quilt_neighbourhood * size)  # the neighbourhoods straddle the line between the halves
    beside_stubble = ~source & (rows < size // 2 - margin)
    beside_pores = ~source & (rows > size // 2 + margin)
    assert 0.75 < out[beside_stubble].std() / texture[source & stubble].std() < 1.25  # 0.91
    assert 0.75 < out[beside_pores].std() / texture[source & ~stubble].std() < 1.25  # 0.93


def test_the_seen_skins_detail_keeps_its_contrast_where_it_fades_into_the_fill():
    """Pores on the seen side, no mirror: where the reliability ramps down towards the visibility
    boundary, the texel's own detail and the fill's are mixed with weights that keep the
    contrast, so there is no band of smoother skin along the seen edge. The least reliable seen
    texels (r ≤ 0.25) keep 0.87 of the reliable skin's fine contrast; mixed linearly, 0.72."""
    size = 512
    ctx = hemisphere_context(size)
    ctx.mirror[...] = -1
    rng = np.random.default_rng(5)
    pores = masked_blur(rng.normal(size=(size, size)).astype(np.float32), np.ones((size, size)), 1.0)
    pores *= 0.06 / pores.std()
    backend, x, visible, log_l = _albedo_with_the_right_hidden(ctx, pores)
    fine = log_l - masked_blur(log_l, ctx.coverage, 3.0)
    reliable = backend.reliability(visible, ctx)
    facing = ctx.coverage & (ctx.normal_camera[..., 2] > 0.6) & (np.abs(ctx.normal_camera[..., 1]) < 0.5)
    core = facing & (reliable > 0.99) & (x < -0.2)
    edge = facing & (visible > 0) & (reliable <= 0.25)
    assert edge.sum() > 500
    assert fine[edge].std() / fine[core].std() > 0.8


def test_foreshortened_seen_skin_keeps_its_own_mottling():
    """Mottling (σ 4–8 texels at S = 512, the band from S/128 to S/64) on the seen side; a wide
    region of it marked as seen at ~75° (normal z 0.25: reliability 0.5 from foreshortening
    alone). Its tone still fades into the fill's base there, but its mottling is the photo's: the
    band keeps 0.94 of the truth's amplitude (faded with the tone, 0.73). No specular reflection
    is modelled (``skin_albedo=None``): the synthetic photo has none."""
    size = 512
    ctx = hemisphere_context(size)
    ctx.mirror[...] = -1
    x = np.linspace(-1, 1, size)[None, :].repeat(size, 0)
    y = np.linspace(1, -1, size)[:, None].repeat(size, 1)
    slanted = ctx.coverage & (x < -0.3)
    ctx.normal_camera[slanted] = [0.0, 0.0, 0.25]  # only the reliability reads it
    rng = np.random.default_rng(7)
    ones = np.ones((size, size))
    noise = rng.normal(size=(size, size)).astype(np.float32)
    mottling = masked_blur(noise, ones, 4.0) - masked_blur(noise, ones, 8.0)
    mottling *= 0.08 / mottling.std()
    truth = srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * np.exp(mottling)[..., None]
    visible = (x < 0.1).astype(np.float32)
    backend = DefaultBackend(settings=DIFFUSE)
    out = srgb_to_linear(backend.homogenise(backend.inpaint(linear_to_srgb(truth) * visible[..., None], visible, ctx), ctx))
    log_l = np.log(np.maximum(out.mean(-1), 1e-4))

    def band(image):
        return masked_blur(image, ctx.coverage, 4.0) - masked_blur(image, ctx.coverage, 8.0)

    region = slanted & (x < -0.4) & (np.hypot(x, y) < 0.85)  # away from its edges
    assert abs(float(backend.reliability(visible, ctx)[region].mean()) - 0.5) < 0.01
    gain = np.polyfit(band(mottling)[region], band(log_l)[region], 1)[0]
    assert 0.85 < gain < 1.1


def test_hidden_side_without_a_mirror_gets_the_seen_skins_own_fine_texture():
    """Right part hidden and no mirror: the fill's finest detail (above S/256 texels⁻¹) is quilted
    from the seen skin, so it has the seen skin's contrast (within 25 %) and its texture: here
    streaks along the rows (stubble combed one way), whose gradient across the rows is over four
    times the one along them on the seen side and over twice in the fill (the blocks' windows cut
    the streaks; isotropic noise would give 1)."""
    import cv2

    size = 512
    ctx = hemisphere_context(size)
    ctx.mirror[...] = -1
    rng = np.random.default_rng(3)
    streaks = cv2.GaussianBlur(rng.normal(size=(size, size)).astype(np.float32), (0, 0), sigmaX=3.0, sigmaY=0.6)
    streaks *= 0.06 / streaks.std()
    _, x, _, log_l = _albedo_with_the_right_hidden(ctx, streaks)
    fine = log_l - masked_blur(log_l, ctx.coverage, size / 256)
    facing = ctx.coverage & (ctx.normal_camera[..., 2] > 0.6)
    seen, hidden = facing & (x < -0.2), facing & (x > 0.4)
    assert 0.75 < fine[hidden].std() / fine[seen].std() < 1.25
    across = np.abs(np.diff(fine, axis=0))[:, :-1]
    along = np.abs(np.diff(fine, axis=1))[:-1, :]
    anisotropy = lambda m: across[m[:-1, :-1]].mean() / along[m[:-1, :-1]].mean()  # noqa: E731
    assert anisotropy(seen) > 4.0 and anisotropy(hidden) > 2.0  # (5.5 and 3.1; value noise's fill: 0.9)


def test_upscale_lanczos():
    m = np.random.default_rng(0).random((16, 16, 3)).astype(np.float32)
    assert DefaultBackend().upscale(m, 4).shape == (64, 64, 3)
    assert DefaultBackend().upscale(m, 1) is m


def test_unseen_texels_get_the_visible_skin_colour_not_the_model_texture():
    ctx = hemisphere_context(64)
    colour = np.array([0.8, 0.6, 0.5], np.float32)
    t_inc = np.broadcast_to(colour, (64, 64, 3)).copy()
    x = np.linspace(-1, 1, 64)[None, :].repeat(64, 0)
    visible = (x < 0.3).astype(np.float32)
    ctx.mirror[...] = -1  # nothing mirrors: the hidden part comes from the seen skin alone
    full = DefaultBackend(settings=DIFFUSE).inpaint(t_inc, visible, ctx)
    hidden = ctx.coverage & (visible == 0)
    np.testing.assert_allclose(full[hidden].mean(axis=0), colour, atol=0.01)


@pytest.fixture(scope="module")
def face_context():
    """The bundled model's mean face 600 mm in front of the camera (S = 256), its texture context."""
    from facegeo import Camera, fit_landmarks, load_model, project
    from facegeo.texturing.context import build_context
    from facegeo.uv.raster import rasterize_uv

    model = load_model()
    camera = Camera.for_image(512, 512)
    lm = project(model.mean_shape[model.landmark_indices].astype(np.float64), np.eye(3), np.array([0, 0, -600.0]), camera)
    return build_context(model, fit_landmarks(model, lm, camera), rasterize_uv(model, size=256))


def _hard_side_light(ctx):
    """A light from the camera's right and above (unit camera-space direction) and the covered
    texels it reaches past the posed mesh's cast shadows ((S, S) bool)."""
    from facegeo.uv import light_visibility

    light = np.array([0.75, 0.25, 0.6])
    light /= np.linalg.norm(light)
    lit = np.zeros(ctx.coverage.shape, bool)
    lit[ctx.coverage] = light_visibility(ctx.vertices_camera, ctx.triangles, ctx.position_camera[ctx.coverage], light)
    return light, lit


def _ggx_render(ctx, albedo, lights, radiance, specular):
    """(N, 3) float64 linear radiance of the covered texels of ``ctx`` (camera at the origin) with
    a constant ``albedo`` (3,), roughness 0.5 and ``specular`` level under the directional
    ``lights`` (K, 3) of ``radiance`` (K, 3), by the GGX shader without a normal map."""
    from facegeo.texturing.ggx import ggx_shaded

    n = ctx.normal_camera[ctx.coverage].astype(np.float64)
    p = ctx.position_camera[ctx.coverage].astype(np.float64)
    tangent = np.cross(n, np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    ones = np.ones((len(n), 1))
    return ggx_shaded(np.broadcast_to(albedo, n.shape).astype(np.float64), np.broadcast_to([0.0, 0, 1], n.shape),
                      0.5 * ones, specular * ones, p, n, tangent, lights, radiance, np.zeros(3), 0.0)


def test_directional_light_and_its_cast_shadows_are_fitted_and_removed(face_context):
    """A constant albedo under a hard light with the posed mesh's cast shadows: the light model
    finds the direction and ambient, and the de-lit skin is flat. The SH fit's directional
    measure of this clean scene is 0.09–0.13 (its trimming drops the shadowed half), below
    directional_range: its irradiance contrast over the sphere (contrast_range) opens the gate."""
    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    shading = 0.08 + np.maximum(ctx.normal_camera @ light, 0.0) * lit  # hard light, dim ambient, cast shadows
    facing = cover & (ctx.normal_camera[..., 2] > 0.2)
    assert (facing & ~lit & (ctx.normal_camera @ light > 0.3)).sum() > 50  # the nose casts a shadow on lit-facing skin
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    photo = linear_to_srgb(np.where(cover[..., None], albedo * shading[..., None], 0.0)).astype(np.float32)
    backend = DefaultBackend(settings=DIFFUSE)  # a diffuse-only photo
    out = backend.homogenise(photo, ctx)
    assert backend.report["analyse"]["directional"] < DEFAULT_SETTINGS.directional_range[0]
    assert backend.report["analyse"]["irradiance_contrast"] > DEFAULT_SETTINGS.contrast_range[1]
    assert backend.report["analyse"]["delighting_strength"] == 1.0
    fitted = np.array(backend.report["light"]["direction"])
    assert np.degrees(np.arccos(np.clip(fitted @ light, -1, 1))) < 3.0
    assert backend.report["light"]["ambient_over_light"] == pytest.approx(0.08, abs=0.02)
    lum = srgb_to_linear(out)[..., 1]
    skin = facing & (ctx.skin > 0.5)
    spread = np.percentile(np.log(lum[skin]), [5, 95])
    assert spread[1] - spread[0] < 0.35  # was > 2 (the shadowed side and the nose's shadow)
    shadowed = skin & ~lit
    assert abs(np.median(np.log(lum[shadowed])) - np.median(np.log(lum[skin & lit]))) < 0.15


def test_no_light_from_below_is_fitted(face_context):
    """Shading that a light from below would make (y −0.9): the light model keeps its direction
    at or above light_min_y (30° below the horizon), where a face as small as a few pixels of
    shading otherwise took one from straight below (RESULTS.md, "a white collar below a dark or
    small face"); under a light from above the same fit finds it within 3°."""
    ctx = face_context
    cover = ctx.coverage
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    angle = lambda a, b: np.degrees(np.arccos(np.clip(a @ b, -1, 1)))  # noqa: E731
    found = {}
    for name, light, settings in (("below", np.array([0.2, -0.9, 0.4]), DIFFUSE),
                                  ("below, any direction", np.array([0.2, -0.9, 0.4]), replace(DIFFUSE, light_min_y=-1.0)),
                                  ("above", np.array([0.3, 0.6, 0.74]), DIFFUSE)):
        light = light / np.linalg.norm(light)
        shading = 0.08 + np.maximum(ctx.normal_camera @ light, 0.0)
        photo = linear_to_srgb(np.where(cover[..., None], albedo * shading[..., None], 0.0)).astype(np.float32)
        backend = DefaultBackend(settings=settings)
        backend.homogenise(photo, ctx)
        found[name] = (light, np.array(backend.report["light"]["direction"]))
    assert DEFAULT_SETTINGS.light_min_y == -0.5 and found["below"][1][1] >= -0.5 - 1e-9
    assert angle(*found["below, any direction"]) < 3.0  # the scene is one of a light from below
    assert angle(*found["above"]) < 3.0


def test_a_warm_sun_and_a_blue_sky_are_both_taken_out(face_context):
    """A constant albedo under a warm sun (cast shadows included) and a blue sky as the ambient
    term: in the photo the shadowed skin's chroma is 0.5 from the lit skin's. One light colour for
    the whole face left the albedo's two 0.51 apart, 0.31 and 0.20 from the truth; with the
    ambient's colour told apart (the de-lit skin's chroma against the texel's ambient share) they
    are 0.04 apart and 0.10 from the truth (the mean light's estimate)."""
    from facegeo.texturing.illuminant import chroma

    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    sun, sky = np.array([1.0, 0.81, 0.63]), np.array([0.59, 0.73, 1.0])
    direct = np.maximum(ctx.normal_camera @ light, 0.0) * lit
    radiance = direct[..., None] * sun + 0.35 * sky
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    photo = linear_to_srgb(np.where(cover[..., None], albedo * radiance, 0.0)).astype(np.float32)
    backend = DefaultBackend(settings=DIFFUSE)  # a diffuse-only photo
    out = srgb_to_linear(backend.homogenise(backend.inpaint(photo, cover.astype(np.float32), ctx), ctx))
    skin = cover & (ctx.normal_camera[..., 2] > 0.3) & (ctx.skin > 0.5)
    in_sun, in_shade = skin & (direct > 0.5), skin & (direct == 0)
    assert in_sun.sum() > 200 and in_shade.sum() > 200
    lin = srgb_to_linear(photo)
    assert np.linalg.norm(np.median(chroma(lin[in_shade]), 0) - np.median(chroma(lin[in_sun]), 0)) > 0.4
    c_sun, c_shade = np.median(chroma(out[in_sun]), 0), np.median(chroma(out[in_shade]), 0)
    assert np.linalg.norm(c_sun - c_shade) < 0.05
    truth = chroma(albedo)
    assert np.linalg.norm(c_sun - truth) < 0.15 and np.linalg.norm(c_shade - truth) < 0.15
    assert backend.report["illuminant"]["ambient_share_spread"] > 0.1


def test_a_clipped_channel_is_restored_from_the_skins_colour_around_it():
    """Skin of one chroma under a brightness ramp, over-exposed so that red clips first, then all
    three: where only red is at the ceiling it comes back from green and blue and the unclipped
    skin's ratios (within 1 %); where all three are, nothing is known and the texel is left as it
    is; no channel is lowered, and a map without clipping is returned as it is."""
    size = 128
    colour = np.array([0.9, 0.6, 0.5], np.float32)
    ramp = np.linspace(0.3, 2.2, size, dtype=np.float32)[None, :, None].repeat(size, 0)
    truth = colour * ramp
    ceiling = srgb_to_linear(np.float32(DEFAULT_SETTINGS.clipped_level))
    photo = np.minimum(truth, 1.0)
    valid = np.ones((size, size), bool)
    out = restore_clipped(photo, valid, size)
    red_only = (truth[..., 0] >= ceiling) & (truth[..., 1:] < ceiling).all(-1)
    every = (truth >= 1.0).all(-1)
    assert red_only.sum() > 100 and every.sum() > 100
    np.testing.assert_allclose(out[red_only], truth[red_only], rtol=0.01)
    np.testing.assert_array_equal(out[every], photo[every])
    assert np.all(out >= photo)
    dim = np.minimum(truth * 0.3, 1.0)
    assert restore_clipped(dim, valid, size) is dim


def test_clipped_texels_are_restored_or_left_out_of_the_light_fit(face_context):
    """The same hard light over-exposed 5×: half the seen skin has a channel at the 8-bit ceiling,
    where the photo gives only a lower bound. Restored from the other channels where some are
    not clipped and left out of the fit where all are, the light comes back (ambient / light
    0.08, direction within 2°); taken as measurements (clipped_level out of reach) they flatten
    the lit side's shading and the fit puts the difference into the ambient and the angle."""
    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    shading = 0.08 + np.maximum(ctx.normal_camera @ light, 0.0) * lit
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    photo = linear_to_srgb(np.clip(np.where(cover[..., None], 5.0 * albedo * shading[..., None], 0.0), 0.0, 1.0)).astype(np.float32)

    def fitted(settings=DIFFUSE):
        backend = DefaultBackend(settings=settings)
        backend.analyse(photo, np.ones(cover.shape, np.float32), ctx)
        direction = np.array(backend.report["light"]["direction"])
        angle = np.degrees(np.arccos(np.clip(direction @ light, -1, 1)))
        return backend.report["light"]["ambient_over_light"], angle, backend.report["analyse"]["clipped_fraction_of_seen_skin"]

    ambient, angle, clipped = fitted()
    assert clipped > 0.4
    assert ambient == pytest.approx(0.08, abs=0.01) and angle < 2.0
    ambient, angle, clipped = fitted(replace(DIFFUSE, clipped_level=2.0))
    assert clipped == 0.0 and (abs(ambient - 0.08) > 0.03 or angle > 4.0)


def test_an_exposure_that_clips_red_gives_the_albedo_of_one_that_does_not(face_context):
    """A key (the hard light) and a fill light, the photo at an exposure and at twice it, where red
    clips on 28 % of the skin, the key-lit side (green and blue do not): the red channel restored
    before the analysis, the lit skin is fitted as the skin it is, and the de-lit albedo's
    luminance on the clipped skin and on the rest keep the ratio they have at the lower exposure.
    (Left out of the fits, the clipped skin took the key light's contrast out of the SH fit: the lit
    side came out 5 % brighter than the rest, at 3 × the exposure twice as bright.)"""
    from facegeo.colour import luminance

    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    fill = np.array([-0.7, 0.1, 0.7]) / np.linalg.norm([-0.7, 0.1, 0.7])
    shading = 0.05 + 0.3 * np.maximum(ctx.normal_camera @ fill, 0.0) + np.maximum(ctx.normal_camera @ light, 0.0) * lit
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    seen = np.ones(cover.shape, np.float32)

    def photo(exposure: float) -> np.ndarray:
        return linear_to_srgb(np.clip(np.where(cover[..., None], exposure * albedo * shading[..., None], 0.0), 0.0, 1.0)).astype(np.float32)

    low, high = photo(1.2), photo(2.4)
    red_clipped = (high[..., 0] >= DIFFUSE.clipped_level) & cover
    assert 0.2 < red_clipped[ctx.skin > 0.5].mean() and not (high[..., 1:] >= DIFFUSE.clipped_level).any()
    ratios = []
    for image in (low, high):
        delit, reliable = DefaultBackend().delight(image, seen, ctx)
        y = luminance(delit)
        trusted = (reliable > 0.5) & (ctx.skin > 0.5)
        ratios.append(np.median(y[trusted & red_clipped]) / np.median(y[trusted & ~red_clipped]))
    assert ratios[1] == pytest.approx(ratios[0], rel=0.02)


def test_the_light_model_at_a_vanishing_strength_de_lights_as_none(face_context):
    """The directional light model switches on at any de-lighting strength above 0; what it
    changes (the shadow dips, the gains' bounds, the environment's sheen) weighs by the strength,
    so a photo just over the SH fit's threshold is de-lit as one just under it (James's even
    render at strength 4e-5: its lips went from 1.09 to 2.19 ΔE00 when its dips and bounds
    switched whole)."""
    from facegeo.colour import luminance

    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    shading = 0.5 + 0.5 * np.maximum(ctx.normal_camera @ light, 0.0) * lit
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    photo = linear_to_srgb(np.clip(np.where(cover[..., None], albedo * shading[..., None], 0.0), 0.0, 1.0)).astype(np.float32)
    seen = np.ones(cover.shape, np.float32)
    probe = DefaultBackend()
    probe.analyse(photo, seen, ctx)
    contrast = probe.report["analyse"]["irradiance_contrast"]
    off = replace(DEFAULT_SETTINGS, directional_range=(5.0, 6.0), contrast_range=(contrast + 1.0, contrast + 2.0))
    barely = replace(off, contrast_range=(contrast - 1e-3, contrast + 99.0))
    results = []
    for settings in (off, barely):
        backend = DefaultBackend(settings=settings)
        delit, reliable = backend.delight(photo, seen, ctx)
        results.append((luminance(delit), backend.report["analyse"]["delighting_strength"], "light" in backend.report))
    (y_off, s_off, light_off), (y_on, s_on, light_on) = results
    assert s_off == 0.0 and not light_off and 0.0 < s_on < 1e-4 and light_on
    skin = cover & (ctx.skin > 0.5)
    assert np.abs(y_on[skin] / y_off[skin] - 1.0).max() < 0.01


def test_a_misplaced_shadow_edge_is_taken_out_and_a_beard_far_from_one_kept(face_context):
    """The hard light's cast shadows rendered 2 texels (~3 mm) off from where the posed mesh puts
    them, and a dark patch (−0.6 in log albedo: a beard) on lit skin far from any shadow's edge:
    within shadow_edge_mm of a cast shadow's edge the left-over dark strip is taken as shadow (its
    de-lit luminance ends nearer the skin's than with no dips looked for), the patch stays as
    dark as it is (before shadow_edge_mm, no dips were looked for under the light model)."""
    from scipy import ndimage

    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    moved = np.roll(lit, 2, axis=1) & cover
    log_albedo = np.full(cover.shape, np.log(0.4), np.float32)
    facing = cover & (ctx.normal_camera[..., 2] > 0.3) & (ctx.skin > 0.5) & (ctx.normal_camera @ light > 0.3)
    edge_mm = ndimage.distance_transform_edt(lit == ndimage.binary_erosion(lit)) * ctx.median_texel_mm
    far = facing & lit & moved & (edge_mm > 25)
    centre = np.argwhere(far)[len(np.argwhere(far)) // 2]
    yy, xx = np.mgrid[: cover.shape[0], : cover.shape[1]]
    beard = far & ((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= 25)
    assert beard.sum() > 20
    log_albedo[beard] -= 0.6
    shading = 0.08 + np.maximum(ctx.normal_camera @ light, 0.0) * moved
    colour = np.exp(log_albedo)[..., None] * np.array([1.1, 0.75, 0.6], np.float32)
    photo = linear_to_srgb(np.where(cover[..., None], colour * shading[..., None], 0.0)).astype(np.float32)
    strip = facing & lit & ~moved  # dark in the photo, lit by the mesh's shadow map

    def delit(tolerance: float) -> np.ndarray:
        backend = DefaultBackend(settings=replace(DIFFUSE, shadow_tolerance=tolerance))
        return np.log(np.maximum(srgb_to_linear(backend.homogenise(photo, ctx))[..., 1], 1e-4))

    with_dips, without = delit(DEFAULT_SETTINGS.shadow_tolerance), delit(10.0)  # (no dip is that deep: none looked for)
    skin_level = np.median(with_dips[facing & lit & moved & ~beard])
    assert strip.sum() > 20
    left_with, left_without = np.median(with_dips[strip]) - skin_level, np.median(without[strip]) - skin_level
    assert left_with > left_without + 0.2  # the strip was ~1.5 darker (the shadow side's ambient)
    assert np.median(with_dips[beard]) - skin_level == pytest.approx(-0.6, abs=0.1)


def test_under_an_even_light_the_meshs_occlusion_is_taken_out_and_a_beard_kept(face_context):
    """An even environment: each texel's irradiance is the posed mesh's own sky visibility
    (:func:`facegeo.uv.sky_visibility`; the nostrils, the eyes' corners and the mouth's are
    occluded), on a constant albedo with a dark patch (−0.6 in log albedo: a beard) on open,
    facing skin. Where the sky is at most half seen, the dips still take out at least 0.3 (log) of
    the occlusion (the photo is ~0.8 below the skin there, the de-lit ~0.4); the patch stays as
    dark as it is (before the mesh's sky bounded the dips, it was taken for a shadow and came out
    0.24 lighter)."""
    from facegeo.uv import sky_visibility

    ctx = face_context
    cover = ctx.coverage
    sky = ctx.surface.to_texels(sky_visibility(ctx.vertices_camera, ctx.triangles)[:, None], ctx.size)[..., 0]
    skin = cover & (ctx.skin > 0.5)
    facing = skin & (ctx.normal_camera[..., 2] > 0.5)
    open_skin = facing & (cv2.erode(np.where(cover, sky, 1.0).astype(np.float32), np.ones((15, 15), np.uint8)) > 0.97)
    centre = np.argwhere(open_skin)[len(np.argwhere(open_skin)) // 2]
    yy, xx = np.mgrid[: cover.shape[0], : cover.shape[1]]
    beard = open_skin & ((yy - centre[0]) ** 2 + (xx - centre[1]) ** 2 <= 25)
    assert beard.sum() > 20
    log_albedo = np.full(cover.shape, np.log(0.4), np.float32)
    log_albedo[beard] -= 0.6
    colour = np.exp(log_albedo)[..., None] * np.array([1.1, 0.75, 0.6], np.float32)
    photo = linear_to_srgb(np.where(cover[..., None], colour * sky[..., None], 0.0)).astype(np.float32)
    backend = DefaultBackend(settings=DIFFUSE)
    delit = np.log(np.maximum(srgb_to_linear(backend.homogenise(photo, ctx))[..., 1], 1e-4))
    assert backend.report["analyse"]["delighting_strength"] == 0.0 and "light" not in backend.report
    skin_level = np.median(delit[open_skin & ~beard])
    occluded = facing & (sky < 0.5)
    shadow = float(np.median(np.log(sky[occluded])))
    assert occluded.sum() > 20 and shadow < -0.7
    assert np.median(delit[occluded]) - skin_level > shadow + 0.3
    assert np.median(delit[beard]) - skin_level == pytest.approx(-0.6, abs=0.1)


def test_the_fill_takes_its_tone_from_the_lit_skin_not_the_shadowed_fringe(face_context):
    """A constant albedo under the hard light whose ambient is 0.08 on the lit side and 0.03 on the
    shadowed one (the head occludes its environment there): one ambient term cannot explain both,
    and the seen band beyond the terminator de-lights ~0.3–0.5 (log) darker than the lit skin.
    The skin hidden past that band takes the lit skin's tone (within 0.2); with the ambient's
    error taken as nil (ambient_log_error = 0: every seen texel the fill's data at its
    reliability) it takes the band's (0.40 darker)."""
    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    n_dot_l = ctx.normal_camera @ light
    shading = np.where(n_dot_l > 0, 0.08, 0.03) + np.maximum(n_dot_l, 0.0) * lit
    albedo = np.array([0.45, 0.3, 0.24], np.float32)
    photo = linear_to_srgb(np.where(cover[..., None], albedo * shading[..., None], 0.0)).astype(np.float32)
    seen = cover & (n_dot_l > -0.35)
    skin = cover & (ctx.skin > 0.5) & (ctx.normal_camera[..., 2] > 0.0)
    hidden = skin & ~seen & (n_dot_l < -0.45)
    assert hidden.sum() > 1000

    def hidden_tone(settings: DefaultSettings = DIFFUSE) -> float:
        backend = DefaultBackend(settings=settings)
        out = srgb_to_linear(backend.homogenise(backend.inpaint(photo, seen.astype(np.float32), ctx), ctx))[..., 1]
        assert "light" in backend.report
        return float(np.median(np.log(out[hidden])) - np.median(np.log(out[skin & seen & (n_dot_l > 0.3)])))

    assert abs(hidden_tone()) < 0.2  # (−0.11)
    assert hidden_tone(replace(DIFFUSE, ambient_log_error=0.0)) < -0.3  # (−0.40)


def test_the_hard_lights_own_sheen_is_taken_out_and_a_diffuse_photo_left_as_it_is(face_context):
    """A constant skin albedo under the hard light rendered by the GGX shader (roughness 0.5,
    specular 0.5), with the posed mesh's cast shadows and a dim white ambient: the lit cheek
    facing the light's mirror direction shows a white sheen, paler and brighter than the skin.
    De-lit, that skin has the albedo's chroma again (without the sheen's removal,
    sun_sheen_lobe_deg → 0, it keeps most of the sheen), and its luminance is the lit skin's.
    The same scene without the sheen (diffuse only) comes out the same with or without it."""
    from facegeo.texturing.illuminant import chroma

    ctx = face_context
    cover = ctx.coverage
    light, lit = _hard_side_light(ctx)
    albedo = np.array([0.5, 0.33, 0.26], np.float32)

    def render(specular: float) -> np.ndarray:
        sun = _ggx_render(ctx, albedo, light[None], np.full((1, 3), np.pi), specular)
        photo = np.zeros((*cover.shape, 3), np.float32)
        photo[cover] = linear_to_srgb(np.clip(sun * lit[cover][:, None] + 0.08 * albedo, 0, 1))
        return photo

    def delit(photo: np.ndarray, lobe_deg: float) -> np.ndarray:
        backend = DefaultBackend(settings=replace(DEFAULT_SETTINGS, sun_sheen_lobe_deg=lobe_deg))
        out = srgb_to_linear(backend.homogenise(backend.inpaint(photo, cover.astype(np.float32), ctx), ctx))
        assert "light" in backend.report
        return out

    skin = cover & (ctx.skin > 0.5) & (ctx.normal_camera[..., 2] > 0.3)
    normal_dot_half = ctx.normal_camera @ ((light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1]))
    sheen = skin & lit & (normal_dot_half > np.cos(np.radians(12)))  # the lobe's core
    matte = skin & lit & (normal_dot_half < np.cos(np.radians(50))) & (ctx.normal_camera @ light > 0.3)
    assert sheen.sum() > 100 and matte.sum() > 100
    truth = chroma(albedo[None])[0]
    photo = render(0.5)
    assert np.linalg.norm(np.median(chroma(srgb_to_linear(photo)[sheen]), axis=0) - truth) > 0.05  # the sheen's pallor (0.096)

    def errors(out: np.ndarray) -> tuple[float, float]:
        colour = np.linalg.norm(np.median(chroma(out[sheen]), axis=0) - truth)
        level = abs(np.median(np.log(luminance(out[sheen]))) - np.median(np.log(luminance(out[matte]))))
        return float(colour), float(level)

    lobe_deg = DEFAULT_SETTINGS.sun_sheen_lobe_deg
    kept, removed = errors(delit(photo, 1e-3)), errors(delit(photo, lobe_deg))
    assert kept[0] > 0.05 and removed[0] < 0.2 * kept[0]  # chroma (0.095 → 0.002)
    assert kept[1] > 0.1 and removed[1] < 0.3 * kept[1]  # the sheen's brightness, log (0.22 → 0.005)
    diffuse = render(0.0)
    np.testing.assert_allclose(delit(diffuse, lobe_deg)[skin], delit(diffuse, 1e-3)[skin], atol=0.01)  # (0.005)


def test_sheen_removal_leaves_grey_skin_and_too_little_reference_alone():
    """Without chroma in the reference skin, or without enough of it, nothing is taken out (and
    nothing is divided by a singular matrix)."""
    rng = np.random.default_rng(0)
    grey = np.repeat(rng.uniform(0.2, 0.6, (32, 32, 1)), 3, axis=-1).astype(np.float32)
    lobe = np.ones((32, 32), np.float32)
    everywhere = np.ones((32, 32), bool)
    with np.errstate(all="raise"):
        assert without_sun_sheen(grey, lobe, everywhere, everywhere, 1.0) is grey
    skin = (grey * np.array([1.0, 0.7, 0.55], np.float32)).astype(np.float32)
    few = np.zeros((32, 32), bool)
    few[:5, :5] = True
    assert without_sun_sheen(skin, lobe, everywhere, few, 1.0) is skin
    pale = skin + 0.1  # white on everything: nothing is brightened, and no channel goes below a tenth
    out = without_sun_sheen(pale, lobe, everywhere, everywhere, 1.0)
    assert np.all(out <= pale + 1e-6) and np.all(out >= 0.1 * pale.min(axis=-1, keepdims=True) - 1e-6)
    assert (out < pale - 1e-3).any()  # the darker texels, paler than the median skin, lose some white


def test_even_light_uses_no_light_model(face_context):
    ctx = face_context
    cover = ctx.coverage
    shading = 0.9 + 0.1 * ctx.normal_camera[..., 2]  # soft, nearly even
    photo = linear_to_srgb(np.where(cover[..., None], np.array([0.45, 0.3, 0.24]) * shading[..., None], 0.0)).astype(np.float32)
    backend = DefaultBackend()
    backend.homogenise(photo, ctx)
    assert backend.report["analyse"]["delighting_strength"] == 0.0 and "light" not in backend.report


def test_a_mole_on_the_seen_cheek_is_not_mirrored_onto_the_hidden_one():
    """Symmetric pores and one dark mole on the seen half: the hidden half takes the mirror's
    pores (correlated with the truth) but not the mole (speck_sigmas), quilted skin there."""
    from scipy import ndimage

    size = 128
    ctx = hemisphere_context(size)
    rng = np.random.default_rng(3)
    pores = rng.normal(size=(size, size)).astype(np.float32)
    pores = 0.5 * (pores + pores[:, ::-1])
    log_lum = 0.06 * pores
    yy, xx = np.mgrid[:size, :size]
    row, col = 60, 40  # seen half (left); its mirror column is size - 1 - col
    mole = (yy - row) ** 2 + (xx - col) ** 2 <= 1  # within the fill's detail band (S/128)
    log_lum[mole] -= 0.6
    truth = np.clip(srgb_to_linear(np.float32([0.78, 0.58, 0.48])) * np.exp(log_lum)[..., None], 0, 1)
    x = np.linspace(-1, 1, size)[None, :].repeat(size, 0)
    visible = (x < 0.0).astype(np.float32)
    backend = DefaultBackend()
    out = srgb_to_linear(backend.inpaint(linear_to_srgb(truth) * visible[..., None], visible, ctx)).mean(-1)
    fine = np.log(out) - masked_blur(np.log(out), ctx.coverage, 3.0)
    mirror_spot = (yy - row) ** 2 + (xx - (size - 1 - col)) ** 2 <= 1
    assert fine[mole].mean() < -0.3  # the mole stays where it was seen
    assert fine[mirror_spot].mean() > -0.05  # and is not copied (-0.28 when it was)
    hidden = ctx.coverage & (x > 0.3) & (ctx.normal_camera[..., 2] > 0.3) & ~ndimage.binary_dilation(mirror_spot, iterations=6)
    assert np.corrcoef(fine[hidden], log_lum[hidden])[0, 1] > 0.5  # the pores are


def test_shading_confidence_is_low_only_where_the_shading_is_steep():
    ctx = hemisphere_context(128)
    x = np.linspace(-1, 1, 128)[None, :].repeat(128, 0)
    flat = shading_confidence(np.ones((128, 128), np.float32), ctx, DEFAULT_SETTINGS)
    assert np.all(flat[ctx.coverage] == 1.0)
    edge = 0.05 + 0.95 / (1 + np.exp(-x / 0.02))  # a cast shadow's edge at x = 0, 20× darker on the left
    conf = shading_confidence(edge.astype(np.float32), ctx, DEFAULT_SETTINGS)
    facing = ctx.coverage & (ctx.normal_camera[..., 2] > 0.5)
    assert conf[facing & (np.abs(x) < 0.02)].max() < 0.05
    assert conf[facing & (np.abs(x) > 0.3)].min() == 1.0


def test_the_sheen_of_a_white_environment_is_taken_out(face_context):
    """A constant skin albedo rendered by the GGX shader (roughness 0.5, F0 0.04: not the
    backend's region priors) under a uniform white environment (300 directional lights over the
    sphere): the photo's skin is greyer where it turns away from the camera (Fresnel). The
    de-lit albedo is the skin's own colour there too, and without the specular model it is not."""
    from facegeo.texturing.illuminant import chroma
    from facegeo.uv.renderer import sphere_directions

    ctx = face_context
    cover = ctx.coverage
    lights = sphere_directions(300)
    radiance = np.full((300, 3), 4 * np.pi / 300)  # radiance 1 from every direction: irradiance π on a plane
    albedo = np.array([0.55, 0.36, 0.28], np.float32)  # luminance 0.39
    lit = _ggx_render(ctx, albedo, lights, radiance, 0.5)
    photo = np.zeros((*cover.shape, 3), np.float32)
    photo[cover] = linear_to_srgb(np.clip(lit * 0.8, 0, 1))
    facing = cover & (ctx.skin > 0.5) & (ctx.normal_camera[..., 2] > 0.35)
    grazing = facing & (ctx.normal_camera[..., 2] < 0.6)
    truth = chroma(albedo[None])[0]

    def chroma_error(backend):
        out = srgb_to_linear(backend.homogenise(photo, ctx))
        return np.linalg.norm(np.median(chroma(out[grazing]), axis=0) - truth), backend.report["analyse"]

    assert grazing.sum() > 200
    photo_error = np.linalg.norm(np.median(chroma(srgb_to_linear(photo)[grazing]), axis=0) - truth)
    kept, _ = chroma_error(DefaultBackend(settings=DIFFUSE))
    removed, report = chroma_error(DefaultBackend())
    assert report["specular_fraction_of_seen_skin"] > 0.05
    assert photo_error > 0.06 and kept > 0.06  # the sheen: the grazing skin's chroma well off the albedo's (0.08)
    assert removed < 0.2 * kept  # 0.003
    with pytest.raises(ValueError, match="skin_albedo"):
        DefaultSettings(skin_albedo=0.0)


def _octave_covariances(image, region, sigmas):
    """3 × 3 covariance of each difference-of-Gaussians octave of ``image`` (S, S, 3) over ``region``."""
    blurred = [masked_blur(image, region, s) for s in sigmas]
    return [np.cov((blurred[k] - blurred[k + 1])[region].T) for k in range(len(sigmas) - 1)]


def test_band_noise_has_the_sources_colour_covariance_per_octave():
    """Source: stationary noise with a known colour mixing (so its octaves have covariance ∝ A Aᵀ)
    on the left half; the noise over the right half, far from the seen skin, has the source's
    covariance in each octave between S/256 and S/32 texels, measured the same way (within 15 %;
    ``strength`` scales it, but not in the octaves finer than ``whole_below``; detail already
    ``present`` is subtracted), is 0 outside ``need``, where the seen skin is near and where it is
    flat, deterministic, and another seed gives another field. It runs on the half-size grid (S/256 =
    4 texels at 1K) and is upsampled."""
    size = 1024
    rng = np.random.default_rng(3)
    ones = np.ones((size, size))
    mixing = np.array([[0.030, 0.0, 0.0], [0.024, 0.012, 0.0], [0.018, 0.006, 0.010]], np.float32)
    texture = masked_blur(rng.normal(size=(size, size, 3)).astype(np.float32), ones, 1.0) @ mixing.T * 4
    half = size // 2
    source = np.zeros((size, size), bool)
    source[:, :half] = True
    need = ~source
    yy, xx = np.mgrid[:size, :size].astype(np.float32)
    position = np.stack([xx * 0.4, yy * 0.4, np.zeros_like(xx)], -1)  # a flat sheet, 0.4 mm texels
    far = np.full((size, size), 1e3, np.float32)
    sigmas = [4.0, 8.0, 16.0, 32.0]
    out = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4)
    assert out.shape == texture.shape and out.dtype == np.float32
    assert np.all(out[source] == 0)
    interior = np.zeros((size, size), bool)
    interior[100:-100, half + 100 : -100] = True
    left = np.zeros((size, size), bool)
    left[100:-100, 100 : half - 100] = True
    wanted = _octave_covariances(texture, source, sigmas)
    for got, want in zip(_octave_covariances(out, need, sigmas), wanted):
        assert np.linalg.norm(got - want) / np.linalg.norm(want) < 0.15
    weaker = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4, strength=0.35)
    for got, want in zip(_octave_covariances(weaker, need, sigmas), wanted):
        assert np.linalg.norm(got - 0.35 * want) / np.linalg.norm(0.35 * want) < 0.15
    # the octaves finer than ``whole_below`` keep (nearly: the layers' spectra overlap, and this
    # spectrum is steep) the whole covariance, the coarser ones ``strength`` of it
    mixed = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4, strength=0.35, whole_below=16.0)
    ratios = [np.trace(got) / np.trace(want) for got, want in zip(_octave_covariances(mixed, need, sigmas), wanted)]
    assert min(ratios[:2]) > 0.75 and abs(ratios[2] - 0.35) < 0.15 * 0.35
    # detail already there counts: half the amplitude present (a quarter of the covariance), three quarters added
    topped = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4, present=0.5 * out, seed=7)
    for got, want in zip(_octave_covariances(topped, need, sigmas), wanted):
        assert np.linalg.norm(got - 0.75 * want) / np.linalg.norm(0.75 * want) < 0.2
    whole = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4, present=out)
    for got, want in zip(_octave_covariances(whole, need, sigmas), wanted):
        assert np.linalg.norm(got) < 0.25 * np.linalg.norm(want)
    coarse = masked_blur(texture, source, 32.0)
    assert np.abs(out[interior]).std() < 2 * np.abs((texture - coarse)[left]).std()  # only the octaves asked for
    np.testing.assert_array_equal(out, band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4))
    other = band_noise(texture, source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4, seed=5)
    assert abs(np.corrcoef(out[interior][:, 0], other[interior][:, 0])[0, 1]) < 0.2
    # next to the seen skin (distance 0) the fill's base holds these octaves: nothing is added
    near = band_noise(texture, source, need, position, np.ones((size, size), bool), np.zeros((size, size), np.float32), 4.0, 32.0, 0.4)
    assert np.all(near == 0)
    # a flat seen skin: nothing to give, and no NaN
    flat = band_noise(np.full_like(texture, -1.0), source, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4)
    assert np.all(flat == 0)
    # too little source: nothing
    tiny = np.zeros((size, size), bool)
    tiny[:5, :5] = True
    assert not band_noise(texture, tiny, need, position, np.ones((size, size), bool), far, 4.0, 32.0, 0.4).any()


def test_band_noise_takes_the_skins_mottling_not_its_folds():
    """Stationary mottling crossed on its source by two strong dark folds (−0.3 over 2 texels:
    nasolabial folds, a shadow's edge): in the octaves between 2 and 8 texels the noise keeps the
    mottling's variance (within 25 %), not the folds-inflated total (1.5–1.9× it)."""
    size = 512
    rng = np.random.default_rng(4)
    ones = np.ones((size, size))
    texture = np.repeat(masked_blur(rng.normal(size=(size, size)).astype(np.float32), ones, 1.0)[..., None] * 0.12, 3, axis=-1)
    folded = texture.copy()
    for row in (100, 300):
        folded[row : row + 2, : size // 2] -= 0.3
    source = np.zeros((size, size), bool)
    source[:, : size // 2] = True
    need = ~source
    yy, xx = np.mgrid[:size, :size].astype(np.float32)
    position = np.stack([xx * 0.4, yy * 0.4, np.zeros_like(xx)], -1)
    far = np.full((size, size), 1e3, np.float32)
    sigmas = [2.0, 4.0, 8.0]
    out = band_noise(folded, source, need, position, np.ones((size, size), bool), far, 2.0, 8.0, 0.4)
    for got, clean, total in zip(_octave_covariances(out, need, sigmas), _octave_covariances(texture, source, sigmas),
                                 _octave_covariances(folded, source, sigmas)):
        assert abs(got[0, 0] / clean[0, 0] - 1) < 0.25
        assert got[0, 0] < 0.75 * total[0, 0]


def test_settings_are_frozen_hashable_and_hold_todays_values():
    """One frozen settings object: no knob can be set on it (a caller derives another with
    dataclasses.replace), and equal settings are equal and hash alike."""
    with pytest.raises(FrozenInstanceError):
        DEFAULT_SETTINGS.fringe_mm = 0.0
    assert DefaultBackend().settings is DEFAULT_SETTINGS
    assert replace(DEFAULT_SETTINGS) == DEFAULT_SETTINGS and hash(replace(DEFAULT_SETTINGS)) == hash(DEFAULT_SETTINGS)
    assert DEFAULT_SETTINGS.fringe_mm == 4.0 and DEFAULT_SETTINGS.quilt_block == 1.0 / 64.0 and DEFAULT_SETTINGS.skin_albedo == 0.4


def test_a_settings_value_passed_to_one_backend_changes_only_its_maps():
    """A non-default value reaches the maps through the settings the backend was given: the
    displacement's limit and depth of one backend, while another backend made at the same time
    with the default settings gives the default maps (nothing global was changed)."""
    ctx = hemisphere_context(64)
    rng = np.random.default_rng(0)
    albedo = (0.6 * np.exp(0.03 * rng.normal(size=(64, 64, 1)))).repeat(3, axis=-1).astype(np.float32)  # fine detail
    albedo[31:33, 31:33] = 0.2  # a dark pit: −1.1 in log luminance, beyond the default limit (0.3 mm)
    shallow = DefaultBackend(settings=replace(DEFAULT_SETTINGS, detail_limit_mm=0.1, detail_depth_mm=0.5))
    default = DefaultBackend()
    d_shallow = shallow.materials(albedo, ctx, maps={"displacement"})["displacement"]
    d_default = default.materials(albedo, ctx, maps={"displacement"})["displacement"]
    assert d_shallow.min() == pytest.approx(-0.1) and d_default.min() == pytest.approx(-DEFAULT_SETTINGS.detail_limit_mm)
    far = ctx.coverage.copy()
    far[24:40, 24:40] = False  # away from the pit: the unclipped detail, half as deep
    assert np.abs(d_default[far]).max() > 0.02
    np.testing.assert_allclose(d_shallow[far], 0.5 * d_default[far], atol=1e-6)
    assert np.array_equal(DefaultBackend().materials(albedo, ctx, maps={"displacement"})["displacement"], d_default)


def test_delight_is_inpaints_first_half_on_the_reliably_seen_texels():
    """A photo of several (facegeo.pipeline.reconstruct_views): delight gives inpaint's de-lit
    albedo where the photo was trusted, nothing where it saw nothing, and the same reliability
    the inpaint kept (seen_reliability)."""
    gamma = np.zeros((3, 9), np.float32)
    gamma[:, 0], gamma[:, 2], gamma[:, 3] = 0.9, 0.2, -0.35
    ctx = hemisphere_context(128)
    albedo = skin_albedo(128)
    e = sh_irradiance(torch.from_numpy(ctx.normal_camera), torch.from_numpy(gamma)).numpy()
    shaded = linear_to_srgb(srgb_to_linear(albedo) * e)
    visible = (ctx.coverage & (np.arange(128)[None, :] < 80)).astype(np.float32)  # the right side unseen
    filled = DefaultBackend(settings=DIFFUSE)
    complete = srgb_to_linear(filled.homogenise(filled.inpaint(shaded, visible, ctx), ctx))
    alone = DefaultBackend(settings=DIFFUSE)
    delit, reliable = alone.delight(shaded, visible, ctx)
    assert delit.dtype == reliable.dtype == np.float32 and delit.shape == (128, 128, 3)
    assert np.array_equal(reliable, filled.seen_reliability(ctx))
    assert reliable[visible == 0].max() == 0.0 and reliable.max() == pytest.approx(1.0)
    trusted = reliable > 0.999
    assert trusted.sum() > 2000
    assert np.abs(delit[trusted] - complete[trusted]).max() < 2e-3
    with pytest.raises(ValueError, match="inpaint this context first"):
        DefaultBackend().seen_reliability(ctx)


def test_the_lips_fill_takes_the_lips_own_chroma_not_the_skins():
    """region_chroma: over a region of its own colour (the lips), what the texels did not take from
    the photo (the unseen ones, and the untrusted share of the seen ones) gets the region's own
    seen chroma instead of the skin-coloured fill's, in proportion to the region's mask; the
    luminance (the log's channel mean) is untouched; texels outside the region, and a region with
    too few trusted texels, are unchanged."""
    from facegeo.texturing.default.fill import region_chroma
    from facegeo.texturing.default.settings import DefaultSettings

    chroma = lambda x: x - x.mean(-1, keepdims=True)  # noqa: E731
    lips = np.log(np.float32([0.40, 0.15, 0.14]))
    skin = np.log(np.float32([0.45, 0.30, 0.25]))
    S = 64
    region = np.zeros((S, S), np.float32)
    region[20:30, 10:50] = 1.0
    region[30:32, 10:50] = 0.5  # the soft border
    seen = np.zeros((S, S), bool)
    seen[20:26, 10:50] = True  # the upper lip seen, the lower one not
    confidence = np.ones((S, S), np.float32)
    reliable = np.where(seen, 0.4, 0.0).astype(np.float32)  # seen, but trusted at 0.4 only
    log_seen = np.where(seen[..., None], lips, 0.0).astype(np.float32)
    own = reliable[..., None]
    out_log = (own * lips + (1 - own) * skin).astype(np.float32)  # the blend: own chroma by the reliability
    settings = DefaultSettings()
    out = region_chroma(out_log, log_seen, seen, reliable, confidence, region, settings)
    np.testing.assert_allclose(out.mean(-1), out_log.mean(-1), atol=1e-5)  # the luminance is the blend's
    np.testing.assert_allclose(chroma(out[22, 30]), chroma(lips), atol=0.02)  # seen at 0.4: all the lips' chroma now
    np.testing.assert_allclose(chroma(out[28, 30]), chroma(lips), atol=0.02)  # unseen lip: the lips' chroma
    half = chroma(out[31, 30])  # the border at 0.5: half way
    np.testing.assert_allclose(half, 0.5 * (chroma(lips) + chroma(out_log[31, 30])), atol=0.02)
    np.testing.assert_array_equal(out[region == 0], out_log[region == 0])
    few = np.zeros((S, S), bool)
    few[20, 10:12] = True  # 2 trusted texels: below the minimum, nothing moves
    np.testing.assert_array_equal(region_chroma(out_log, log_seen, few, np.where(few, 0.4, 0.0), confidence, region, settings), out_log)
    assert region_chroma(out_log, log_seen, seen, reliable, confidence, None, settings) is out_log


def test_a_texel_whose_shading_is_in_doubt_keeps_its_own_chroma():
    """own_chroma: where only the shading's confidence made the fill take over (reliable =
    reliability × confidence), the texel's chroma is its own by its reliability alone and its
    luminance (the channel mean of the log) the blend's; where the confidence is 1, or the
    texel unseen, the blend is kept."""
    from facegeo.texturing.default.fill import own_chroma

    lips = np.log(np.float32([0.40, 0.15, 0.14]))  # a red lip, seen
    filled = np.log(np.float32([0.45, 0.30, 0.25]))  # what the fill made there (the skin around)
    confidence = np.float32([[0.5, 0.5, 1.0, 0.5]])
    reliability = np.float32([[1.0, 0.6, 0.6, 0.0]])
    reliable = reliability * confidence
    seen = np.array([[True, True, True, False]])
    log_seen = np.broadcast_to(lips, (1, 4, 3)).astype(np.float32)
    out_log = (reliable[..., None] * lips + (1 - reliable[..., None]) * filled).astype(np.float32)  # the fill's blend
    out = own_chroma(out_log, log_seen, seen, reliable, confidence)
    chroma = lambda x: x - x.mean(-1, keepdims=True)  # noqa: E731
    np.testing.assert_allclose(out.mean(-1), out_log.mean(-1), atol=1e-6)  # the luminance is the blend's
    for texel in (0, 1):  # the own chroma by the reliability alone: 1.0 and 0.6 (the blend gave 0.5 and 0.3)
        expected = reliability[0, texel] * chroma(lips) + (1 - reliability[0, texel]) * chroma(filled)
        np.testing.assert_allclose(chroma(out[0, texel]), expected, atol=1e-5)
    np.testing.assert_array_equal(out[0, 2:], out_log[0, 2:])  # confidence 1, or unseen: unchanged


def test_the_fills_detail_is_the_same_on_one_thread_and_on_two(monkeypatch):
    # fill_detail quilts the seen skin's finest detail on one thread while it makes the noise's
    # layers on another (they meet when the noise counts the quilted detail): the same numbers
    import facegeo.texturing.default.fill as fill_module

    size = 256
    ctx = hemisphere_context(size)
    ctx.mirror[...] = -1  # no mirror: the hidden side is quilted and given the noise
    rng = np.random.default_rng(5)
    _, x, _, log_l = _albedo_with_the_right_hidden(ctx, 0.05 * rng.normal(size=(size, size)).astype(np.float32))
    log_rgb = np.repeat(log_l[..., None], 3, axis=-1) + np.array([0.1, 0.0, -0.1], np.float32)
    seen = ctx.coverage & (x < 0.2)
    inner = np.where(seen, 10.0, 0.0).astype(np.float32)
    reliable = seen.astype(np.float32)
    made, noises = {}, []
    monkeypatch.setattr(fill_module, "coloured_noise", lambda *args: noises.append(args[0]) or coloured_noise(*args))
    for threads in (1, 2):
        monkeypatch.setattr(fill_module, "usable_threads", lambda: threads)
        made[threads] = fill_module.fill_detail(log_rgb, seen, inner, reliable, ctx, DEFAULT_SETTINGS)
    assert len(noises) == 2 and all(layers is not None for layers in noises)  # quilted, and the noise's layers made
    for one, two in zip(made[1], made[2]):
        np.testing.assert_array_equal(one, two)
