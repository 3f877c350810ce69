"""Tests of facegeo.photo: every odd photo file becomes a plain RGB array or a clear InputError."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image, ImageFile, ImageOps

from facegeo.errors import InputError
from facegeo.photo import MIN_SIDE, Photo, as_rgb_uint8, load_photo


def pattern(h: int = 48, w: int = 64) -> np.ndarray:
    """An asymmetric (H, W, 3) uint8 RGB pattern: smooth gradients plus a red top-left block."""
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([(x * 255 // (w - 1)), (y * 255 // (h - 1)), ((x + 2 * y) % 256)], axis=-1)
    img = img.astype(np.uint8)
    img[: h // 4, : w // 4] = (255, 0, 0)
    return img


def blocky(h: int = 48, w: int = 64) -> np.ndarray:
    """Large flat quadrants (survive JPEG compression): red TL, green TR, blue BL, white BR."""
    img = np.zeros((h, w, 3), np.uint8)
    img[: h // 2, : w // 2] = (255, 0, 0)
    img[: h // 2, w // 2:] = (0, 255, 0)
    img[h // 2:, : w // 2] = (0, 0, 255)
    img[h // 2:, w // 2:] = (255, 255, 255)
    return img


def save(path, img: Image.Image | np.ndarray, **kw):
    if isinstance(img, np.ndarray):
        img = Image.fromarray(img)
    img.save(path, **kw)
    return path


def assert_clean(photo: Photo) -> None:
    img = photo.image
    assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3
    assert img.flags.c_contiguous


# ---------------------------------------------------------------------------------------------
# plain files
# ---------------------------------------------------------------------------------------------


def test_plain_png_roundtrip(tmp_path):
    img = pattern()
    p = save(tmp_path / "face.png", img)
    photo = load_photo(p)
    assert_clean(photo)
    np.testing.assert_array_equal(photo.image, img)
    assert photo.scale == 1.0
    assert photo.original_size == (64, 48)
    assert photo.notes == ()
    assert photo.path == str(p)
    assert photo.size == (64, 48)


def test_plain_jpeg_with_png_name(tmp_path):
    """The format is sniffed from the content, not the extension."""
    p = save(tmp_path / "face.png", blocky(), format="JPEG", quality=95, subsampling=0)
    photo = load_photo(p)
    assert np.abs(photo.image.astype(int) - blocky().astype(int)).max() < 40


# ---------------------------------------------------------------------------------------------
# files that are not (whole) images
# ---------------------------------------------------------------------------------------------


def test_text_file_named_jpg(tmp_path):
    p = tmp_path / "face.jpg"
    p.write_text("this is not a photo\n")
    with pytest.raises(InputError) as ei:
        load_photo(p)
    msg = str(ei.value)
    assert str(p) in msg and "image" in msg and "a readable PNG/JPEG/... image" in msg
    assert ei.value.field == "image"


def test_empty_file(tmp_path):
    p = tmp_path / "empty.png"
    p.write_bytes(b"")
    with pytest.raises(InputError, match="empty file") as ei:
        load_photo(p)
    assert str(p) in str(ei.value)


def test_missing_file(tmp_path):
    p = tmp_path / "nope.jpg"
    with pytest.raises(InputError, match="no such file") as ei:
        load_photo(p)
    assert str(p) in str(ei.value)


def test_directory(tmp_path):
    with pytest.raises(InputError, match="a directory") as ei:
        load_photo(tmp_path)
    assert str(tmp_path) in str(ei.value)


def test_unreadable_file(tmp_path, monkeypatch):
    """chmod 000 does not stop root, so the permission error is simulated."""
    p = save(tmp_path / "locked.png", pattern())

    def deny(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(Image, "open", deny)
    with pytest.raises(InputError, match="permission denied") as ei:
        load_photo(p)
    assert str(p) in str(ei.value)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG"])
@pytest.mark.parametrize("global_truncated_flag", [False, True])
def test_truncated(tmp_path, monkeypatch, fmt, global_truncated_flag):
    """Half a file is an error, even if someone switched on LOAD_TRUNCATED_IMAGES globally."""
    monkeypatch.setattr(ImageFile, "LOAD_TRUNCATED_IMAGES", global_truncated_flag)
    rng = np.random.default_rng(0)
    noisy = rng.integers(0, 256, (128, 128, 3), dtype=np.uint8)  # incompressible: real data
    buf = io.BytesIO()
    Image.fromarray(noisy).save(buf, format=fmt)
    data = buf.getvalue()
    p = tmp_path / f"cut.{fmt.lower()}"
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="truncated or corrupt") as ei:
        load_photo(p)
    assert str(p) in str(ei.value)
    assert ImageFile.LOAD_TRUNCATED_IMAGES is global_truncated_flag  # restored


@pytest.mark.parametrize("size", [(1, 1), (31, 200), (200, 31)])
def test_too_small(tmp_path, size):
    w, h = size
    p = save(tmp_path / "tiny.png", np.zeros((h, w, 3), np.uint8))
    with pytest.raises(InputError, match=f"{w}x{h} px") as ei:
        load_photo(p)
    assert ei.value.field == "image size" and str(MIN_SIDE) in ei.value.expected


def test_min_side_accepted(tmp_path):
    p = save(tmp_path / "ok.png", np.zeros((MIN_SIDE, MIN_SIDE, 3), np.uint8))
    assert load_photo(p).image.shape == (MIN_SIDE, MIN_SIDE, 3)


def test_decompression_bomb(tmp_path, monkeypatch):
    p = save(tmp_path / "bomb.png", np.zeros((64, 64, 3), np.uint8))
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 1000)  # 4096 px > 2 x limit: an error
    with pytest.raises(InputError, match="decompression bomb") as ei:
        load_photo(p)
    assert str(p) in str(ei.value)


# ---------------------------------------------------------------------------------------------
# depths, modes, transparency
# ---------------------------------------------------------------------------------------------


def test_16bit_rgb_png_scaled_by_257(tmp_path):
    rng = np.random.default_rng(1)
    a = rng.integers(0, 65536, (40, 50, 3), dtype=np.uint16)
    a[0, 0] = (65535, 0, 32768)  # edge values
    a[0, 1] = (128, 129, 257 * 100 + 128)
    p = tmp_path / "deep.png"
    assert cv2.imwrite(str(p), a[:, :, ::-1])  # BGR on disk
    photo = load_photo(p)
    expected = np.round(a / 257.0).astype(np.uint8)
    np.testing.assert_array_equal(photo.image, expected)
    assert tuple(photo.image[0, 0]) == (255, 0, 128)
    assert tuple(photo.image[0, 1]) == (0, 1, 100)
    assert "16-bit image reduced to 8 bit" in photo.notes


def test_16bit_rgba_png(tmp_path):
    a = np.full((40, 40, 4), 65535, np.uint16)
    a[..., 0] = 0  # cyan, opaque
    a[:20, :, 3] = 0  # top half fully transparent
    p = tmp_path / "deep_alpha.png"
    assert cv2.imwrite(str(p), a[:, :, [2, 1, 0, 3]])
    photo = load_photo(p)
    assert (photo.image[:20] == 255).all()
    assert (photo.image[20:] == (0, 255, 255)).all()
    assert "alpha channel composited over white" in photo.notes
    assert "16-bit image reduced to 8 bit" in photo.notes


def test_16bit_grey_png(tmp_path):
    g = (np.arange(48 * 48, dtype=np.uint32).reshape(48, 48) * 28).astype(np.uint16)
    p = tmp_path / "grey16.png"
    Image.fromarray(g).save(p)  # Pillow mode I;16
    assert Image.open(p).mode.startswith("I")
    photo = load_photo(p)
    expected = np.round(g / 257.0).astype(np.uint8)
    np.testing.assert_array_equal(photo.image, np.repeat(expected[..., None], 3, axis=2))
    assert "16-bit image reduced to 8 bit" in photo.notes
    assert "greyscale expanded to RGB" in photo.notes


def test_greyscale_L(tmp_path):
    g = pattern()[..., 0]
    p = save(tmp_path / "grey.png", Image.fromarray(g, "L"))
    photo = load_photo(p)
    np.testing.assert_array_equal(photo.image, np.stack([g] * 3, axis=-1))
    assert "greyscale expanded to RGB" in photo.notes


def test_greyscale_LA(tmp_path):
    g = np.full((40, 40), 100, np.uint8)
    a = np.full((40, 40), 255, np.uint8)
    a[:, :20] = 0
    p = save(tmp_path / "la.png", Image.fromarray(np.dstack([g, a]), "LA"))
    photo = load_photo(p)
    assert (photo.image[:, :20] == 255).all()
    assert (photo.image[:, 20:] == 100).all()
    assert "alpha channel composited over white" in photo.notes
    assert "greyscale expanded to RGB" in photo.notes


def test_bilevel(tmp_path):
    g = np.zeros((40, 40), np.uint8)
    g[:, 20:] = 255
    p = save(tmp_path / "bw.png", Image.fromarray(g).convert("1"))
    photo = load_photo(p)
    assert (photo.image[:, :20] == 0).all() and (photo.image[:, 20:] == 255).all()


def test_cmyk_jpeg(tmp_path):
    rgb = blocky()
    p = save(tmp_path / "cmyk.jpg", Image.fromarray(rgb).convert("CMYK"), quality=95,
             subsampling=0)
    assert Image.open(p).mode == "CMYK"
    photo = load_photo(p)
    assert "CMYK converted to RGB" in photo.notes
    assert np.abs(photo.image.astype(int) - rgb.astype(int))[4:-4, 4:-4].max() < 40
    # quadrant centres have the right colours
    assert tuple(photo.image[12, 16]) == pytest.approx((255, 0, 0), abs=20)
    assert tuple(photo.image[36, 16]) == pytest.approx((0, 0, 255), abs=20)


def test_rgba_composited_over_white(tmp_path):
    img = np.zeros((40, 40, 4), np.uint8)
    img[..., 0] = 200  # red-ish
    img[:, :10, 3] = 0  # transparent
    img[:, 10:20, 3] = 128  # half
    img[:, 20:, 3] = 255  # opaque
    p = save(tmp_path / "rgba.png", Image.fromarray(img, "RGBA"))
    photo = load_photo(p)
    assert (photo.image[:, :10] == 255).all()
    half = photo.image[0, 15]
    assert tuple(half) == (round((200 * 128 + 255 * 127) / 255), round(255 * 127 / 255),
                           round(255 * 127 / 255))
    assert (photo.image[:, 20:] == (200, 0, 0)).all()
    assert "alpha channel composited over white" in photo.notes


def test_palette_with_transparency(tmp_path):
    idx = np.zeros((40, 40), np.uint8)
    idx[:, 20:] = 1
    im = Image.fromarray(idx, "P")
    im.putpalette([0, 0, 0, 10, 200, 30] + [0] * (256 * 3 - 6))
    p = save(tmp_path / "pal.png", im, transparency=0)
    photo = load_photo(p)
    assert (photo.image[:, :20] == 255).all()
    assert (photo.image[:, 20:] == (10, 200, 30)).all()
    assert "alpha channel composited over white" in photo.notes


def test_palette_without_transparency(tmp_path):
    idx = np.zeros((40, 40), np.uint8)
    im = Image.fromarray(idx, "P")
    im.putpalette([9, 8, 7] * 256)
    photo = load_photo(save(tmp_path / "pal.png", im))
    assert (photo.image == (9, 8, 7)).all()
    assert "alpha channel composited over white" not in photo.notes


# ---------------------------------------------------------------------------------------------
# EXIF orientation
# ---------------------------------------------------------------------------------------------

EXPECTED_TRANSFORM = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.transpose(1, 0, 2),
    6: lambda a: np.rot90(a, -1),  # clockwise
    7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),
    8: lambda a: np.rot90(a, 1),  # counter-clockwise
}


def _exif(orientation: int) -> Image.Exif:
    exif = Image.Exif()
    exif[0x0112] = orientation
    return exif


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_png_exact(tmp_path, orientation):
    img = pattern()
    p = save(tmp_path / f"o{orientation}.png", img, exif=_exif(orientation))
    photo = load_photo(p)
    expected = EXPECTED_TRANSFORM[orientation](img)
    np.testing.assert_array_equal(photo.image, expected)
    with Image.open(p) as im:  # the same as Pillow's own exif_transpose
        np.testing.assert_array_equal(photo.image, np.asarray(ImageOps.exif_transpose(im).convert("RGB")))
    assert photo.original_size == (expected.shape[1], expected.shape[0])
    assert photo.image.flags.c_contiguous
    assert any(f"orientation {orientation}" in n for n in photo.notes) == (orientation != 1)


def test_exif_orientation_6_jpeg_rotates_clockwise(tmp_path):
    """Orientation 6: the camera was turned; the displayed image is the stored one turned 90° CW.

    Stored (H=48, W=64): red top-left, green top-right, blue bottom-left, white bottom-right.
    After a clockwise quarter turn (W=48, H=64): blue top-left, red top-right,
    white bottom-left, green bottom-right.
    """
    img = blocky(48, 64)
    p = save(tmp_path / "rot6.jpg", img, exif=_exif(6), quality=95, subsampling=0)
    photo = load_photo(p)
    out = photo.image
    assert out.shape == (64, 48, 3)
    assert photo.original_size == (48, 64)
    with Image.open(p) as im:
        ref = np.asarray(ImageOps.exif_transpose(im))
    np.testing.assert_array_equal(out, ref)
    assert np.abs(out.astype(int) - np.rot90(img, -1).astype(int)).max() < 60
    near = lambda px, rgb: np.abs(px.astype(int) - np.array(rgb)).max() < 30  # noqa: E731
    assert near(out[8, 8], (0, 0, 255))  # top-left: blue
    assert near(out[8, 40], (255, 0, 0))  # top-right: red
    assert near(out[56, 8], (255, 255, 255))  # bottom-left: white
    assert near(out[56, 40], (0, 255, 0))  # bottom-right: green
    assert "EXIF orientation 6 applied (rotated 90° clockwise)" in photo.notes


# ---------------------------------------------------------------------------------------------
# size and frames
# ---------------------------------------------------------------------------------------------


def test_downscale_area(tmp_path):
    img = np.ascontiguousarray(np.tile(pattern(), (5, 5, 1)))  # 240 x 320
    p = save(tmp_path / "big.png", img)
    photo = load_photo(p, max_side=160)
    assert photo.image.shape == (120, 160, 3)
    assert photo.scale == pytest.approx(0.5)
    assert photo.original_size == (320, 240)
    expected = cv2.resize(img, (160, 120), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(photo.image, expected)
    assert "downscaled from 320x240 to 160x120" in photo.notes
    assert photo.image.flags.c_contiguous


def test_downscale_default_max_side(tmp_path):
    img = np.zeros((100, 3000, 3), np.uint8)
    photo = load_photo(save(tmp_path / "wide.png", img))
    assert photo.image.shape == (68, 2048, 3)
    assert photo.scale == pytest.approx(2048 / 3000)
    assert "downscaled from 3000x100 to 2048x68" in photo.notes


def test_downscale_after_rotation(tmp_path):
    """max_side applies to the displayed (rotated) image; the note names rotated sizes."""
    img = np.zeros((64, 128, 3), np.uint8)
    photo = load_photo(save(tmp_path / "r.png", img, exif=_exif(8)), max_side=64)
    assert photo.image.shape == (64, 32, 3)
    assert photo.original_size == (64, 128)
    assert "downscaled from 64x128 to 32x64" in photo.notes


def test_too_thin_after_downscale(tmp_path):
    img = np.zeros((40, 400, 3), np.uint8)
    with pytest.raises(InputError, match="after downscaling"):
        load_photo(save(tmp_path / "thin.png", img), max_side=200)


def test_max_side_must_be_sane(tmp_path):
    p = save(tmp_path / "x.png", pattern())
    with pytest.raises(ValueError):
        load_photo(p, max_side=8)


def _frames():
    colours = [(255, 0, 0), (0, 255, 0), (0, 0, 255)]
    return [Image.fromarray(np.full((40, 40, 3), c, np.uint8)) for c in colours]


@pytest.mark.parametrize("fmt", ["GIF", "TIFF"])
def test_multi_frame_first_frame(tmp_path, fmt):
    frames = _frames()
    p = tmp_path / f"anim.{fmt.lower()}"
    frames[0].save(p, format=fmt, save_all=True, append_images=frames[1:])
    photo = load_photo(p)
    assert (photo.image == (255, 0, 0)).all()
    assert "first of 3 frames used" in photo.notes
    assert photo.image.flags.c_contiguous


def test_other_formats(tmp_path):
    img = pattern()
    for fmt, ext in [("BMP", "bmp"), ("TIFF", "tif"), ("PPM", "ppm"), ("WEBP", "webp")]:
        p = tmp_path / f"x.{ext}"
        kw = {"lossless": True} if fmt == "WEBP" else {}
        Image.fromarray(img).save(p, format=fmt, **kw)
        np.testing.assert_array_equal(load_photo(p).image, img, err_msg=fmt)


def test_a_png_or_jpeg_imports_only_its_own_pillow_plugin(tmp_path):
    """A photo whose signature names its format loads that format's plugin alone (the others cost
    ~10 ms of a fit's start); any other file still gets every plugin of the formats offered."""
    import subprocess
    import sys

    img = pattern()
    for fmt, ext in [("PNG", "png"), ("JPEG", "jpg"), ("BMP", "bmp")]:
        Image.fromarray(img).save(tmp_path / f"x.{ext}", format=fmt)
    code = ("import sys; from facegeo.photo import load_photo; "
            "plugins = lambda: sorted(m[4:] for m in sys.modules if m.startswith('PIL.') and m.endswith('ImagePlugin')); "
            f"load_photo({str(tmp_path / 'x.png')!r}); print(plugins()); "
            f"load_photo({str(tmp_path / 'x.jpg')!r}); print(plugins()); "
            f"print(load_photo({str(tmp_path / 'x.bmp')!r}).image.shape, 'TiffImagePlugin' in plugins())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out[:2] == ["['PngImagePlugin']", "['JpegImagePlugin', 'PngImagePlugin']"]
    assert out[2] == f"{img.shape} True"


def test_photo_validates_image():
    with pytest.raises(ValueError):
        Photo(image=np.zeros((4, 4), np.uint8), path="x", scale=1.0, original_size=(4, 4))


# ---------------------------------------------------------------------------------------------
# as_rgb_uint8
# ---------------------------------------------------------------------------------------------

dims = st.integers(1, 12)


@settings(max_examples=60, deadline=None)
@given(h=dims, w=dims, c=st.sampled_from([None, 1, 3, 4]),
       dtype=st.sampled_from([np.uint8, np.uint16, np.float16, np.float32, np.float64]),
       data=st.data(), transpose=st.booleans())
def test_as_rgb_uint8_valid(h, w, c, dtype, data, transpose):
    shape = (h, w) if c is None else (h, w, c)
    if np.dtype(dtype).kind == "f":
        elements = st.floats(0.0, 1.0, width=np.dtype(dtype).itemsize * 8)
    else:
        elements = st.integers(0, np.iinfo(dtype).max)
    arr = data.draw(hnp.arrays(dtype, shape, elements=elements))
    if transpose:  # a non-contiguous view of the same values
        arr = np.swapaxes(np.ascontiguousarray(np.swapaxes(arr, 0, 1)), 0, 1)
    out = as_rgb_uint8(arr)
    assert out.shape == (h, w, 3) and out.dtype == np.uint8 and out.flags.c_contiguous
    assert not np.shares_memory(out, arr)

    a3 = arr if arr.ndim == 3 else arr[..., None]
    colour = a3[..., :3] if a3.shape[2] >= 3 else np.repeat(a3[..., :1], 3, axis=2)
    if a3.shape[2] == 4:
        m = 1.0 if np.dtype(dtype).kind == "f" else float(np.iinfo(dtype).max)
        alpha = a3[..., 3:].astype(np.float64) / m
        comp = (colour.astype(np.float64) / m) * alpha + (1.0 - alpha)
        expected = comp * 255.0
        assert np.abs(out.astype(np.float64) - expected).max() <= 0.51  # two roundings
        return
    if dtype == np.uint8:
        np.testing.assert_array_equal(out, colour)
    elif dtype == np.uint16:
        np.testing.assert_array_equal(out, np.round(colour / 257.0).astype(np.uint8))
    else:
        expected = np.floor(colour.astype(np.float32 if dtype != np.float64 else np.float64)
                            * 255.0 + 0.5)
        np.testing.assert_array_equal(out, expected.astype(np.uint8))
    if a3.shape[2] == 1:
        assert (out[..., 0] == out[..., 1]).all() and (out[..., 1] == out[..., 2]).all()


@settings(max_examples=40, deadline=None)
@given(shape=hnp.array_shapes(min_dims=1, max_dims=4, min_side=1, max_side=6))
def test_as_rgb_uint8_bad_shapes(shape):
    ok = (len(shape) == 2) or (len(shape) == 3 and shape[2] in (1, 3, 4))
    arr = np.zeros(shape, np.uint8)
    if ok:
        assert as_rgb_uint8(arr).shape == shape[:2] + (3,)
    else:
        with pytest.raises(InputError, match="image array shape"):
            as_rgb_uint8(arr, source="mem")


@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.int8, np.uint32, bool, np.complex64, object])
def test_as_rgb_uint8_bad_dtypes(dtype):
    with pytest.raises(InputError, match="dtype"):
        as_rgb_uint8(np.zeros((4, 4, 3), dtype=dtype))


@pytest.mark.parametrize("value, found", [(np.nan, "NaN"), (np.inf, "infinite"), (1.5, "1.5"),
                                          (-0.25, "-0.25")])
def test_as_rgb_uint8_bad_floats(value, found):
    arr = np.zeros((4, 4, 3), np.float32)
    arr[1, 2, 0] = value
    with pytest.raises(InputError, match=found) as ei:
        as_rgb_uint8(arr, source="buffer")
    assert str(ei.value).startswith("buffer: image array values")


def test_as_rgb_uint8_empty_and_not_array():
    with pytest.raises(InputError, match="H, W >= 1"):
        as_rgb_uint8(np.zeros((0, 5, 3), np.uint8))
    with pytest.raises(InputError, match="numpy array"):
        as_rgb_uint8([[0, 0], [0, 0]])  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"\(4, 4, 2\)"):
        as_rgb_uint8(np.zeros((4, 4, 2), np.uint8))


def test_as_rgb_uint8_tiny_float_overshoot_clipped():
    arr = np.full((2, 2, 3), 1.0 + 1e-7, np.float64)
    assert (as_rgb_uint8(arr) == 255).all()
