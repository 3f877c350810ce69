"""The light's colour: estimated from the skin locus and the white references, removed with the
luminance kept; a greyscale photo's invented chroma."""

import numpy as np
import pytest

from facegeo.colour import is_greyscale, luminance
from facegeo.texturing.illuminant import (AMBIENT_CHROMA_TOLERANCE, AMBIENT_SHARE_SPREAD, FIRM_FACTOR, NEUTRAL_TOLERANCE, PLANCKIAN,
                                          SCLERA_CHROMA, SKIN_CHROMA, SKIN_LOCUS, WHITE_COOL_SHARE, WHITE_GATE, WHITE_SKIN_TINT_GAP,
                                          WHITE_TINT_GATE, ambient_chroma_trend, chroma,
                                          estimate_illuminant, firm_shrinkage, invent_chroma, remove_cast)


def test_neutral_light_on_any_skin_tone_is_left_alone():
    for t in (-0.2, 0.0, 0.2):  # lighter to darker skin along the locus
        light, report = estimate_illuminant(SKIN_CHROMA + t * SKIN_LOCUS, SCLERA_CHROMA)
        np.testing.assert_allclose(light, 0.0, atol=1e-9)
        assert report["white_used"]


def test_warm_light_is_recovered_with_the_sclera_whole():
    """A strong light is not shortened by the neutral tolerance (firm, not soft, threshold)."""
    warm = 0.6 * PLANCKIAN  # a strong tungsten cast
    light, report = estimate_illuminant(SKIN_CHROMA + 0.1 * SKIN_LOCUS + warm, SCLERA_CHROMA + warm)
    assert report["white_used"]
    assert np.linalg.norm(light - warm) < 0.02
    np.testing.assert_allclose(light / np.linalg.norm(light), PLANCKIAN, atol=0.05)  # the right direction
    without, _ = estimate_illuminant(SKIN_CHROMA + 0.1 * SKIN_LOCUS + warm)
    assert np.linalg.norm(light - warm) < np.linalg.norm(without - warm) < 0.1  # the sclera helps; the skin alone gets near


def test_firm_shrinkage_leaves_near_neutral_lights_alone_and_strong_ones_whole():
    lengths = np.linspace(0.0, 0.5, 501)
    shrunk = np.array([x * firm_shrinkage(x) for x in lengths])
    assert np.all(shrunk[lengths <= NEUTRAL_TOLERANCE] == 0.0)
    strong = lengths >= FIRM_FACTOR * NEUTRAL_TOLERANCE
    np.testing.assert_allclose(shrunk[strong], lengths[strong])
    assert np.all(np.diff(shrunk) >= 0) and np.max(np.diff(shrunk)) < 3 * (lengths[1] - lengths[0])  # monotone, continuous


def test_a_white_reference_redder_than_the_skin_is_not_used():
    skin = SKIN_CHROMA + 0.3 * PLANCKIAN
    lid = skin + np.array([WHITE_GATE + 0.5, 0.1])  # reddish lids picked for a tiny eye
    light, report = estimate_illuminant(skin, lid)
    assert not report["white_used"] and report["white_miss"] > WHITE_GATE
    np.testing.assert_allclose(light, estimate_illuminant(skin)[0])


def test_a_neutral_sclera_beside_skin_yellower_than_the_locus_is_used():
    """Skin yellower than the locus under a neutral light reads, alone, as skin under a warm
    light; its sclera, cooler than that predicts by more than the gate, is used (lid skin only
    makes a white warmer), and the light is then taken as neutral. The same miss towards warmer
    (lid skin) is not used."""
    skin = SKIN_CHROMA + np.array([0.0, -0.45])  # off the locus: much less blue (a scan's baked-in light)
    predicted = estimate_illuminant(skin)[0]
    cool = SCLERA_CHROMA + predicted - (WHITE_GATE + 0.1) * PLANCKIAN  # beyond the gate, cooler
    light, report = estimate_illuminant(skin, cool)
    assert report["white_used"]
    assert report["white_miss"] == pytest.approx(WHITE_COOL_SHARE * (WHITE_GATE + 0.1), abs=1e-9)
    assert np.linalg.norm(light) < np.linalg.norm(predicted)  # towards the white's neutral light
    warm = SCLERA_CHROMA + predicted + (WHITE_GATE + 0.1) * PLANCKIAN
    _, report = estimate_illuminant(skin, warm)
    assert not report["white_used"] and report["white_miss"] == pytest.approx(WHITE_GATE + 0.1, abs=1e-9)


def test_a_lid_in_the_shade_is_not_a_white_but_a_tinted_sclera_is():
    """A shut eye's lid in a sky's shade: the skin's chroma moved along the Planckian locus towards
    cool, so far that it passes the miss gate, but with the skin's own tint (magenta of any light):
    not used. A sclera with lid skin mixed in, as tinted but well below the skin's tint, is."""
    normal = np.array([-PLANCKIAN[1], PLANCKIAN[0]])
    skin = np.array([0.68, -0.23])  # a ruddy light skin under a near-neutral light (tint ~0.4)
    lid = skin - 0.45 * PLANCKIAN
    light, report = estimate_illuminant(skin, lid)
    assert report["white_miss"] <= WHITE_GATE  # the miss alone would have taken it
    assert report["white_tint"] > WHITE_TINT_GATE and not report["white_used"]
    np.testing.assert_allclose(light, estimate_illuminant(skin)[0])
    skin_tint = float((skin - SCLERA_CHROMA) @ normal)
    sclera = SCLERA_CHROMA + 0.2 * PLANCKIAN + (skin_tint - 2 * WHITE_SKIN_TINT_GAP) * normal
    _, report = estimate_illuminant(skin, sclera)
    assert report["white_tint"] > WHITE_TINT_GATE and report["white_used"]


def test_remove_cast_divides_the_light_and_keeps_luminance():
    rng = np.random.default_rng(0)
    albedo = rng.uniform(0.05, 0.9, (100, 3)).astype(np.float32)
    light = np.array([0.3, -0.4])
    lit = albedo * np.exp([light[0], 0.0, light[1]]).astype(np.float32)
    out = remove_cast(lit, light)
    np.testing.assert_allclose(luminance(out), luminance(lit), rtol=1e-5)
    np.testing.assert_allclose(chroma(out), chroma(albedo), atol=1e-5)


def test_remove_cast_takes_a_light_per_texel():
    rng = np.random.default_rng(1)
    albedo = rng.uniform(0.05, 0.9, (4, 5, 3)).astype(np.float32)
    light = rng.uniform(-0.5, 0.5, (4, 5, 2))
    lit = albedo * np.exp(np.stack([light[..., 0], np.zeros((4, 5)), light[..., 1]], -1)).astype(np.float32)
    np.testing.assert_allclose(chroma(remove_cast(lit, light)), chroma(albedo), atol=1e-5)


def test_ambient_chroma_trend_finds_a_cooler_ambient_and_leaves_skins_own_variation():
    rng = np.random.default_rng(2)
    n = 5000
    share = rng.uniform(0.0, 0.8, n)
    weight = rng.uniform(0.5, 1.0, n)
    skin = rng.normal(0.0, 0.05, (n, 2))  # the skin's own chroma scatter
    delta = np.array([-0.4, 0.5])  # a bluer ambient (sky) than the directional light (sun)
    found, mean, report = ambient_chroma_trend(skin + share[:, None] * delta, share, weight)
    np.testing.assert_allclose(found, (delta @ PLANCKIAN) * PLANCKIAN, atol=0.01)  # its part along the Planckian locus
    np.testing.assert_allclose(report["ambient_chroma_slope"], delta, atol=0.01)
    assert mean == pytest.approx(np.average(share, weights=weight))
    assert report["ambient_share_spread"] == pytest.approx(0.8 / np.sqrt(12), abs=0.01)
    # skin whose colour varies with its shading by less than the tolerance: no light colour
    weak = -0.8 * AMBIENT_CHROMA_TOLERANCE / report["ambient_share_spread"] * PLANCKIAN
    assert np.all(ambient_chroma_trend(skin + share[:, None] * weak, share, weight)[0] == 0.0)
    # skin redder and warmer in shade (as its own colour is): not taken for a light
    assert np.all(ambient_chroma_trend(skin - share[:, None] * delta, share, weight)[0] == 0.0)
    # one light does nearly all the lighting: nothing to tell apart
    narrow = 0.3 + 0.5 * AMBIENT_SHARE_SPREAD * (share - 0.4) / 0.8
    assert np.all(ambient_chroma_trend(skin + narrow[:, None] * delta, narrow, weight)[0] == 0.0)


def test_invented_chroma_has_the_luminance_and_skin_or_lip_chroma():
    lum = np.linspace(0.05, 0.8, 50).astype(np.float32)
    lips = np.zeros(50, np.float32)
    lips[25:] = 1.0
    rgb = invent_chroma(lum, lips)
    np.testing.assert_allclose(luminance(rgb), lum, rtol=1e-5)
    c = chroma(rgb)
    np.testing.assert_allclose(c[:25], np.broadcast_to(SKIN_CHROMA, (25, 2)), atol=1e-5)
    assert np.all(c[25:, 0] > c[:25, 0].max())  # lips redder


def test_greyscale_detection_allows_jpeg_noise_but_not_colour():
    rng = np.random.default_rng(1)
    grey = np.repeat(rng.uniform(0, 1, (1000, 1)), 3, axis=1)
    noisy = np.clip(grey + rng.integers(-1, 2, grey.shape) / 255.0, 0, 1)
    assert is_greyscale(grey) and is_greyscale(noisy)
    skin = grey * np.array([1.0, 0.8, 0.7])
    assert not is_greyscale(skin) and not is_greyscale(np.zeros((0, 3)))


def test_a_white_reference_in_shade_is_read_at_the_eyes_ambient_share():
    """A sun and a cooler sky: the skin's light moves with its ambient share, and the sclera sits
    where that share is high (its socket in the sun's shadow). Read at the skin's mean share it
    would make the whole light as cool as the sky; read at the eyes' share, the mean light is found."""
    from types import SimpleNamespace

    from facegeo.texturing.default.light_colour import ambient_trend, light_colour, light_colour_map

    size = 64
    share = np.broadcast_to(np.linspace(0.1, 0.9, size, dtype=np.float32), (size, size)).copy()  # ambient share, left to right
    eyes = np.zeros((size, size), bool)
    eyes[20:26, 52:58] = True  # where the face is mostly in the sun's shadow
    weight = (~eyes).astype(np.float32)
    light = 0.4 * PLANCKIAN  # the mean light: warm (beyond the shrinkage towards neutral)
    sky = -0.5 * PLANCKIAN  # the chroma per unit of ambient share: the sky is cooler
    mean_share = float(np.average(share, weights=weight))
    c = SKIN_CHROMA + light + (share[..., None] - mean_share) * sky
    free = np.stack([np.exp(c[..., 0]), np.ones((size, size)), np.exp(c[..., 1])], axis=-1).astype(np.float32) * 0.3
    white_chroma = SCLERA_CHROMA + light + (share[eyes].mean() - mean_share) * sky
    ctx = SimpleNamespace(white_reference=np.array([np.exp(white_chroma[0]), 1.0, np.exp(white_chroma[1])]) * 0.5,
                          regions={"eyes": eyes.astype(np.float32)}, coverage=np.ones((size, size), bool))
    trend = ambient_trend(free, share, weight)
    np.testing.assert_allclose(trend.delta, sky, atol=1e-6)
    found, report = light_colour(free, weight, ctx, trend)
    naive, _ = light_colour(free, weight, ctx)  # the reference read at the mean share
    assert report["white_used"] and np.linalg.norm(found - light) < 0.02
    assert np.linalg.norm(naive - light) > 0.1 and float((naive - light) @ PLANCKIAN) < 0  # taken for a cooler light
    np.testing.assert_allclose(report["white_ambient_shift"], (share[eyes].mean() - mean_share) * sky, atol=1e-6)
    # the light map: the mean light plus the trend, and the trend's figures reported
    per_texel = light_colour_map(found, trend, report)
    np.testing.assert_allclose(per_texel[:, 32] - found, (share[:, 32, None] - trend.mean) * sky, atol=1e-5)
    assert report["ambient_chroma"] == pytest.approx(list(sky))
