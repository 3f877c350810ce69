"""One albedo from several photos (facegeo.texturing.fusion): exposure and white balance matched
to the reference, each texel from the photos that see it best, no seam, the reference's fill where
nobody saw."""

from __future__ import annotations

import numpy as np
import pytest

from facegeo.texturing.fusion import MIN_COMMON_TEXELS, fuse_albedos, view_weight

S = 128


def textured(seed: int = 0) -> np.ndarray:
    """A skin-like linear albedo with detail at every scale."""
    rng = np.random.default_rng(seed)
    detail = rng.normal(0.0, 0.08, (S, S, 1)).astype(np.float32)
    y, x = np.mgrid[0:S, 0:S] / S
    base = np.stack([0.45 + 0.1 * x, 0.3 + 0.05 * y, 0.22 + 0.0 * x], -1).astype(np.float32)
    return np.clip(base * np.exp(detail), 0.0, 1.0)


def test_exposure_and_white_balance_are_matched_and_each_side_comes_from_the_photo_that_saw_it():
    truth = textured()
    cover = np.ones((S, S), bool)
    left = np.zeros((S, S), np.float32)
    left[:, : S // 2 + 16] = 1.0  # the reference sees the left and a band in the middle
    right = np.zeros((S, S), np.float32)
    right[:, S // 2 - 16:] = 1.0  # the other photo the right and the same band
    gain = np.array([0.6, 0.7, 0.9], np.float32)  # darker and bluer: another exposure and white balance
    reference_albedo = np.where(left[..., None] > 0, truth, 0.5)  # elsewhere its backend's fill (wrong)
    other = np.where(right[..., None] > 0, truth * gain, 0.0)
    fused, report = fuse_albedos([reference_albedo, other], [left, right], cover, cover, reference=0)
    assert report["gains"][1] == pytest.approx(list(1 / gain), rel=1e-3)
    assert report["common_texels"][1] == 32 * S and report["notes"] == []
    # the right side is the other photo's, brought to the reference's exposure, the left the
    # reference's (within 1-2 %: the blend's coarse band reaches past the band both saw, where each
    # photo's albedo is continued from what it saw); no seam in the band both saw
    assert np.abs(fused[:, S // 2 + 24:] - truth[:, S // 2 + 24:]).max() < 5e-3
    assert np.abs(fused[:, : S // 2 - 24] - truth[:, : S // 2 - 24]).max() < 5e-3
    assert np.abs(fused - truth).max() < 1e-2


def test_the_photo_that_sees_a_texel_best_dominates_it_and_unseen_texels_keep_the_reference():
    truth = textured(1)
    cover = np.ones((S, S), bool)
    near = np.full((S, S), 1.0, np.float32)
    far = np.full((S, S), 0.25, np.float32)  # sees everything, at a quarter of the pixels per mm²
    blurred = np.clip(truth * np.exp(np.random.default_rng(5).normal(0, 0.05, (S, S, 3))), 0, 1).astype(np.float32)
    fused, report = fuse_albedos([blurred, truth], [far, near], cover, cover, reference=0)
    # weight 0.25^4 against 1: the near photo's texels, within its (unit) gain's error
    assert np.median(np.abs(fused - truth)) < 0.3 * np.median(np.abs(blurred - truth))
    assert report["share"] == [0.0, 1.0]
    nobody = np.zeros((S, S), np.float32)
    only, _ = fuse_albedos([blurred, truth], [nobody, nobody], cover, cover, reference=0)
    assert np.abs(only - blurred).max() < 1e-4  # nobody saw anything: the reference's fill


def test_photos_that_share_too_little_skin_are_not_matched_and_a_note_says_so():
    truth = textured(2)
    cover = np.ones((S, S), bool)
    a = np.zeros((S, S), np.float32)
    a[:, :60] = 1
    b = np.zeros((S, S), np.float32)
    b[:, 70:] = 1
    _, report = fuse_albedos([truth, truth * 0.5], [a, b], cover, cover, reference=0)
    assert report["common_texels"][1] < MIN_COMMON_TEXELS and report["gains"][1] == [1.0, 1.0, 1.0]
    assert "not matched" in report["notes"][0] and report["notes"][0].startswith("photo 1:")


def test_view_weight_is_visibility_times_pixels_per_square_mm():
    w = view_weight(np.array([[1.0, 0.5, 1.0]]), np.array([[1.0, 1.0, 0.5]]), np.array([[500.0, 500.0, 1000.0]]), 1000.0)
    assert w.dtype == np.float32 and w[0] == pytest.approx([4.0, 2.0, 0.5])


def test_mismatched_inputs_are_refused():
    with pytest.raises(ValueError):
        fuse_albedos([], [], np.ones((S, S), bool), np.ones((S, S), bool))
    with pytest.raises(ValueError):
        fuse_albedos([np.zeros((S, S, 3), np.float32)], [np.zeros((S, 4), np.float32)], np.ones((S, S), bool), np.ones((S, S), bool))


def test_a_photo_of_another_face_is_left_out_by_its_implausible_gains():
    truth = textured(3)
    cover = np.ones((S, S), bool)
    everywhere = np.ones((S, S), np.float32)
    other_face = np.clip(truth * np.array([1.0, 0.45, 0.4], np.float32) * 1.6, 0, 1)  # redder: another person, another light
    fused, report = fuse_albedos([truth, other_face], [everywhere, everywhere * 4], cover, cover, reference=0)
    assert report["notes"][0].startswith("photo 1: left out of the texture")
    assert np.abs(fused - truth).max() < 1e-4 and report["share"] == [1.0, 0.0]
