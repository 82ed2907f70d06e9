"""Depth images in and out: 16-bit PNG (millimetres by default) and ``.npy`` (float metres, or
16-bit integers in depth units).

PNGs are read with Pillow (a dependency of the package). Written PNGs (the development scenes)
are 16-bit greyscale, encoded here with zlib.
"""

from __future__ import annotations

import io
import struct
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from itnet.scene.camera import SceneInputError, SceneTooLargeError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
DEFAULT_DEPTH_SCALE = 1000.0  # depth units per metre of a 16-bit image: millimetres


def png_to_depth(data: bytes, max_pixels: int | None = None) -> NDArray[np.uint16]:
    """PNG bytes -> the 16-bit depth image (H, W). SceneInputError for anything else: not a
    PNG, colour, or another bit depth (an 8-bit image cannot hold depth in millimetres), or
    more than ``max_pixels`` (checked on the header, before decoding)."""
    if not data.startswith(PNG_SIGNATURE):
        raise SceneInputError("not a PNG image")
    if len(data) < 33 or data[12:16] != b"IHDR":
        raise SceneInputError("truncated PNG (no header)")
    width, height, bit_depth, colour = struct.unpack(">IIBB", data[16:26])
    if bit_depth != 16 or colour != 0:
        kind = {0: "greyscale", 2: "RGB", 3: "palette", 4: "greyscale+alpha", 6: "RGBA"}
        raise SceneInputError(
            f"a depth PNG must be 16-bit greyscale; this one is {bit_depth}-bit "
            f"{kind.get(colour, f'colour type {colour}')}"
        )
    if max_pixels is not None and width * height > max_pixels:
        raise SceneTooLargeError(
            f"the depth image has {width}x{height} pixels, over the limit of {max_pixels}"
        )
    try:
        from PIL import Image
    except ImportError:
        raise SceneInputError("reading PNG depth images needs Pillow: pip install pillow") from None
    try:
        with Image.open(io.BytesIO(data)) as image:
            depth = np.asarray(image, dtype=np.uint16)
    except (OSError, ValueError, SyntaxError) as err:
        raise SceneInputError(f"unreadable PNG ({err})") from None
    if depth.shape != (height, width):
        raise SceneInputError(f"unexpected PNG layout {depth.shape} for {width}x{height}")
    return depth


def depth_to_png(depth: NDArray[np.uint16]) -> bytes:
    """A 16-bit depth image (H, W) -> PNG bytes (greyscale, 16-bit, big-endian rows)."""
    d = np.ascontiguousarray(depth, dtype=">u2")
    h, w = d.shape
    rows = np.concatenate([np.zeros((h, 1), np.uint8), d.view(np.uint8).reshape(h, 2 * w)], 1)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return (
            struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
        )

    header = struct.pack(">IIBBBBB", w, h, 16, 0, 0, 0, 0)
    return (PNG_SIGNATURE + chunk(b"IHDR", header)
            + chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) + chunk(b"IEND", b""))  # fmt: skip


def depth_in_metres(image: NDArray, depth_scale: float | None = None) -> NDArray[np.float64]:
    """A depth image (H, W): integers are depth units (``depth_scale`` per metre, default
    millimetres), floats are metres unless ``depth_scale`` says otherwise -> metres (0: none)."""
    if image.ndim != 2:
        raise SceneInputError(f"a depth image must be 2-D (H, W), got shape {image.shape}")
    if depth_scale is not None and not (np.isfinite(depth_scale) and depth_scale > 0):
        raise SceneInputError(f"depth_scale must be a positive number, got {depth_scale}")
    if np.issubdtype(image.dtype, np.integer):
        return image.astype(np.float64) / (depth_scale or DEFAULT_DEPTH_SCALE)
    if np.issubdtype(image.dtype, np.floating):
        return image.astype(np.float64) / (depth_scale or 1.0)
    raise SceneInputError(f"a depth image must hold numbers, got {image.dtype}")


def read_npy(data: bytes) -> NDArray:
    """``.npy`` bytes -> the array (no pickles)."""
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise SceneInputError(f"not a readable .npy array ({err})") from None


def read_bytes(path: Path) -> bytes:
    if not path.is_file():
        raise SceneInputError("no such file")
    return path.read_bytes()
