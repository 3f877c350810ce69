"""The albedo's level (facegeo.texturing.default.albedo_level): set by the skin prior and the
white references, not by the photo's exposure."""

from dataclasses import replace

import numpy as np
import pytest

from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear
from facegeo.texturing.default import DEFAULT_SETTINGS, DefaultBackend
from facegeo.texturing.default.albedo_level import SKIN_PATCHES, _locus_place, albedo_level, skin_prior_luminance
from test_default_backend import hemisphere_context, skin_albedo

PATCHES = [srgb_to_linear(np.asarray(p, np.float32) / 255.0) for p in SKIN_PATCHES]


def test_the_skin_prior_runs_through_the_colorchecker_skin_patches():
    full = replace(DEFAULT_SETTINGS, level_tone_share=1.0, level_skin_range=(0.01, 1.0))
    for patch in PATCHES:  # the published patches: luminance 0.35 (light skin) and 0.10 (dark skin)
        assert skin_prior_luminance(_locus_place(patch), full) == pytest.approx(float(luminance(patch)), rel=1e-5)
    middle = np.sqrt(float(luminance(PATCHES[0])) * float(luminance(PATCHES[1])))
    assert middle == pytest.approx(0.188, abs=1e-3)
    halfway = np.mean([_locus_place(p) for p in PATCHES])
    assert skin_prior_luminance(halfway, DEFAULT_SETTINGS) == pytest.approx(middle, rel=1e-5)
    assert skin_prior_luminance(None, DEFAULT_SETTINGS) == pytest.approx(middle, rel=1e-5)  # greyscale: the middle
    # half the slope: the light patch's place gives the geometric mean of the middle and its luminance
    assert skin_prior_luminance(_locus_place(PATCHES[0]), DEFAULT_SETTINGS) == pytest.approx(
        np.sqrt(middle * float(luminance(PATCHES[0]))), rel=1e-5)
    # flat beyond the patches: redder than dark skin is a ruddy face or a warm light, not darker skin
    for beyond, patch in ((-5.0, PATCHES[0]), (5.0, PATCHES[1])):
        assert skin_prior_luminance(beyond, DEFAULT_SETTINGS) == skin_prior_luminance(_locus_place(patch), DEFAULT_SETTINGS)
    narrow = replace(DEFAULT_SETTINGS, level_skin_range=(0.15, 0.25))  # bounded
    assert skin_prior_luminance(-5.0, narrow) == 0.25 and skin_prior_luminance(5.0, narrow) == 0.15


def _uniform(y: float, size: int = 32) -> np.ndarray:
    """(size, size, 3) linear skin of luminance ``y`` (the light patch's chroma)."""
    return np.broadcast_to(PATCHES[0] * (y / float(luminance(PATCHES[0]))), (size, size, 3)).astype(np.float32)


def test_a_white_reference_and_the_skin_prior_are_combined_by_their_precisions():
    albedo, weight, shading = _uniform(0.1), np.ones((32, 32), np.float32), np.full((32, 32), 0.8, np.float32)
    tone = 0.1
    prior_k = skin_prior_luminance(tone, DEFAULT_SETTINGS) / 0.1
    white_k = prior_k * np.exp(0.4)  # 0.4 apart in log: within the gate
    white = np.full(3, DEFAULT_SETTINGS.level_white_reflectance / white_k * 0.8)  # seen under the eyes' shading 0.8
    k, report = albedo_level(albedo, weight, shading, None, white, tone, DEFAULT_SETTINGS)
    ps, pw = DEFAULT_SETTINGS.level_skin_sigma ** -2, DEFAULT_SETTINGS.level_white_sigma ** -2
    assert report["used"] == ["skin_prior", "white_reference"]
    assert report["cues"]["white_reference"]["k"] == pytest.approx(white_k, rel=1e-5)
    assert k == pytest.approx(np.exp((ps * np.log(prior_k) + pw * np.log(white_k)) / (ps + pw)), rel=1e-5)
    assert report["skin_luminance"] == pytest.approx(0.1 * k, rel=1e-5)
    # a "white" five times darker than the skin (a scan's grey eyes) contradicts the prior: not used
    k_dark, report = albedo_level(albedo, weight, shading, None, np.full(3, 0.02), tone, DEFAULT_SETTINGS)
    assert report["used"] == ["skin_prior"] and report["cues"]["white_reference"]["miss_sigma"] > DEFAULT_SETTINGS.level_gate
    assert k_dark == pytest.approx(prior_k, rel=1e-5)
    # whatever the cues say, the skin stays within the skin range
    dim = white * 0.1  # a white ten times darker asks for a ten times larger k: beyond a narrow range's top
    narrow = replace(DEFAULT_SETTINGS, level_skin_range=(0.05, 0.2), level_gate=10.0)
    _, report = albedo_level(albedo, weight, shading, None, dim, -5.0, narrow)
    assert report["used"] == ["skin_prior", "white_reference"] and report["skin_luminance"] == pytest.approx(0.2, rel=1e-5)
    # too little seen skin: the photo's level is kept, and the report says so
    k_none, report = albedo_level(albedo, np.zeros((32, 32), np.float32), shading, None, None, tone, DEFAULT_SETTINGS)
    assert k_none == 1.0 and "note" in report


def test_the_albedo_does_not_follow_the_exposure_and_the_relit_texture_does():
    """The same skin under the same light at two exposures a stop apart (no channel clipped):
    one albedo; inpaint's relit texture keeps each photo's own level."""
    size = 128
    ctx = hemisphere_context(size)
    albedo = srgb_to_linear(skin_albedo(size))
    light = np.array([0.5, 0.3, 0.8]) / np.linalg.norm([0.5, 0.3, 0.8])
    shading = np.clip(ctx.normal_camera @ light, 0.0, None) * 0.8 + 0.2
    vis = ctx.coverage.astype(np.float32)
    albedos, relit = [], []
    for exposure in (0.5, 1.0):
        photo = linear_to_srgb(np.clip(albedo * shading[..., None] * exposure, 0.0, 1.0)).astype(np.float32)
        assert srgb_to_linear(photo)[ctx.coverage].max() < 0.99
        backend = DefaultBackend()
        full = backend.inpaint(photo, vis, ctx)
        albedos.append(backend.homogenise(full, ctx))
        relit.append(full)
    inner = ctx.coverage & (ctx.normal_camera[..., 2] > 0.5)
    assert np.abs(albedos[0] - albedos[1])[inner].max() < 2.0 / 255  # one albedo
    # the relit texture is under each photo's exposure (a stop apart), as it was before the level
    ratio = np.median(luminance(srgb_to_linear(relit[0]))[inner] / luminance(srgb_to_linear(relit[1]))[inner])
    assert ratio == pytest.approx(0.5, rel=0.01)
