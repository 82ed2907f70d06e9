import io

import numpy as np
import pytest
from PIL import Image

from itnet.scene import SceneInputError, SceneTooLargeError
from itnet.scene.depth_io import depth_in_metres, depth_to_png, png_to_depth


def test_png_round_trip_is_exact():
    rng = np.random.default_rng(0)
    depth = rng.integers(0, 65535, size=(7, 5), dtype=np.uint16)
    assert np.array_equal(png_to_depth(depth_to_png(depth)), depth)


def test_pillow_reads_the_written_png_as_16_bit():
    depth = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    image = Image.open(io.BytesIO(depth_to_png(depth)))
    assert image.size == (4, 3) and np.array_equal(np.asarray(image), depth)


def test_an_8_bit_png_is_the_wrong_bit_depth():
    out = io.BytesIO()
    Image.fromarray(np.zeros((4, 4), np.uint8)).save(out, format="PNG")
    with pytest.raises(SceneInputError, match="16-bit greyscale.*8-bit"):
        png_to_depth(out.getvalue())


def test_not_a_png_and_a_truncated_png_are_refused():
    with pytest.raises(SceneInputError, match="not a PNG"):
        png_to_depth(b"GIF89a")
    with pytest.raises(SceneInputError):
        png_to_depth(depth_to_png(np.ones((4, 4), np.uint16))[:40])


def test_the_pixel_limit_is_checked_on_the_header():
    with pytest.raises(SceneTooLargeError, match="over the limit"):
        png_to_depth(depth_to_png(np.ones((10, 10), np.uint16)), max_pixels=99)


def test_depth_units():
    assert depth_in_metres(np.array([[1500]], np.uint16))[0, 0] == 1.5
    assert depth_in_metres(np.array([[1500]], np.uint16), depth_scale=5000)[0, 0] == 0.3
    assert depth_in_metres(np.array([[1.5]], np.float32))[0, 0] == 1.5
