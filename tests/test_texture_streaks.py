"""Issue 49, "No streaks": a greyscale photo's seen region ends on a darker fringe (hair strands,
the background at a silhouette, a dark padding's join that the photo's mask let through), which
the mask, without chroma, could not tell from skin; and a crop padded at its border repeats its
last line of the cheek. Neither may leave a line or streaks in the albedo."""

import numpy as np

from facegeo.colour import linear_to_srgb, luminance, srgb_to_linear
from facegeo.skin_mask import PAD_MIN_LINES, padded_border
from facegeo.texturing.default import DefaultBackend
from facegeo.texturing.default.occluders import grey_fringe
from test_default_backend import hemisphere_context


def _greyscale_face_with_a_dark_fringe(size=128, fringe=(0.45, 0.6, 0.8)):
    """The hemisphere's greyscale skin, seen right of column 40, with a broad variation of its
    tone along rows (as a real face's de-lit skin varies over the face: the global spread that
    hides a fringe from a test against the whole face) and a fringe darkening the seen region's
    first texels (``fringe``: the factors of columns 40, 41, ...), as a mask's edge lets through."""
    ctx = hemisphere_context(size)
    rng = np.random.default_rng(5)
    row = np.arange(size)[:, None].repeat(size, 1)
    column = np.arange(size)[None, :].repeat(size, 0)
    tone = np.exp(0.45 * np.sin(2 * np.pi * row / 48.0) + 0.03 * rng.normal(size=(size, size))).astype(np.float32)
    truth = np.float32(0.25) * tone
    seen = (column >= 40) & ctx.coverage
    photo = truth.copy()
    for k, factor in enumerate(fringe):
        photo[column == 40 + k] *= factor
    photo = np.repeat(photo[..., None], 3, axis=-1)
    return ctx, photo, seen, row, column


def _albedo_line(out_lum, ctx, row, column):
    """The darkest column's median ratio, over the rows near the middle, of the albedo's
    luminance to the same row's skin well inside the seen region (columns 52–60)."""
    rows = (row[:, 0] >= 34) & (row[:, 0] < 94)
    reference = np.median(out_lum[rows][:, 52:60], axis=1, keepdims=True)
    ratio = out_lum[rows] / reference
    return min(float(np.median(ratio[:, c])) for c in range(34, 50))


def test_a_greyscale_photos_dark_fringe_at_the_seen_edge_leaves_no_line():
    ctx, photo, seen, row, column = _greyscale_face_with_a_dark_fringe()
    backend = DefaultBackend()
    t_inc = linear_to_srgb(photo) * seen[..., None]
    out = srgb_to_linear(backend.homogenise(backend.inpaint(t_inc, seen.astype(np.float32), ctx), ctx))
    assert backend.report["illuminant"]["greyscale"]
    # before issue 49 the fringe stayed: a line at 0.72 of the skin beside it
    assert _albedo_line(luminance(out), ctx, row, column) > 0.9


def test_grey_fringe_marks_the_edges_step_not_the_skins_own_variation():
    ctx, photo, seen, row, column = _greyscale_face_with_a_dark_fringe()
    backend = DefaultBackend()
    from facegeo.texturing.default.reliability import inner_distance, reliability

    w = seen.astype(np.float32)
    inner = inner_distance(seen, ctx)
    fit_mask = seen & (reliability(w, inner, ctx, backend.settings) > 0.5)
    marked = grey_fringe(photo, np.ones(seen.shape, np.float32), w, inner, fit_mask, ctx, backend.settings)
    middle = (row >= 34) & (row < 94)
    assert np.median(marked[middle & (column == 40)]) == 1.0 and np.median(marked[middle & (column == 41)]) == 1.0
    # the skin's own variation, its rows' broad swing included, is not a fringe
    assert marked[middle & seen & (column >= 46)].max() == 0.0
    # no step, no fringe
    flat = np.where(seen[..., None], photo, 0.0)
    flat[:, 40:43] = flat[:, 46:49]
    assert grey_fringe(flat, np.ones(seen.shape, np.float32), w, inner, fit_mask, ctx, backend.settings)[middle & seen].max() == 0.0


def _photo(h=120, w=90, seed=0):
    rng = np.random.default_rng(seed)
    base = np.linspace(60, 200, w)[None, :, None] + np.linspace(0, 40, h)[:, None, None]
    return np.clip(base + rng.normal(0, 6, (h, w, 3)), 0, 255).astype(np.uint8)


def test_a_crops_repeated_border_is_found_on_every_side():
    photo = _photo()
    padded = np.pad(photo, ((7, 3), (12, 0), (0, 0)), mode="edge")
    expected = np.zeros(padded.shape[:2], bool)
    expected[:7] = expected[-3:] = expected[:, :12] = True
    np.testing.assert_array_equal(padded_border(padded), expected)


def test_a_photo_without_padding_has_none_nor_a_flat_band():
    photo = _photo(seed=1)
    assert not padded_border(photo).any()
    one = np.pad(photo, ((0, 0), (PAD_MIN_LINES - 1, 0), (0, 0)), mode="edge")  # one repeated line: a photo's own
    assert not padded_border(one).any()
    # a flat band (a wall, a constant padding) draws no streaks and may be the photo's own
    assert not padded_border(np.pad(photo, ((0, 0), (0, 9), (0, 0)), mode="constant", constant_values=17)).any()
