"""Reading and writing point clouds: .ply, .pcd, .xyz/.pts/.txt, .npy (pure numpy, no open3d).

Every reader returns an (N, 3) float64 array of x, y, z; other per-point fields are ignored.
Anything that cannot be read raises ``CloudReadError`` with a message that names the file and the
problem, so callers can report it and move on.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

SUFFIXES = (".ply", ".pcd", ".xyz", ".pts", ".txt", ".npy")
MAX_HEADER_BYTES = 64 * 1024
# LZF's longest back-reference: 3 bytes of input -> 264 bytes of output. A compressed PCD that
# claims more than this ratio is corrupt; checking it first bounds memory by the file's size.
LZF_MAX_RATIO = 88
# Errors that numpy and the parsers raise on malformed input; all become CloudReadError.
_PARSE_ERRORS = (
    ValueError,
    TypeError,
    IndexError,
    KeyError,
    OverflowError,
    EOFError,
    UnicodeDecodeError,
)
_PCD_KINDS = {"F": ("f", (2, 4, 8)), "I": ("i", (1, 2, 4, 8)), "U": ("u", (1, 2, 4, 8))}

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


class CloudReadError(ValueError):
    """A point-cloud file is missing, unreadable, or not a cloud."""


def read_cloud(path: str | Path) -> NDArray[np.float64]:
    """Read a cloud file -> (N, 3) float64. Raises CloudReadError."""
    path = Path(path)
    if not path.is_file():
        raise CloudReadError(f"{path}: no such file")
    suffix = path.suffix.lower()
    readers = {".ply": _read_ply, ".pcd": _read_pcd, ".npy": _read_npy}
    reader = readers.get(suffix, _read_text if suffix in SUFFIXES else None)
    if reader is None:
        raise CloudReadError(f"{path}: unknown format {suffix!r} (known: {', '.join(SUFFIXES)})")
    try:
        data = path.read_bytes()
        points = np.asarray(reader(data), dtype=np.float64).reshape(-1, 3)
    except CloudReadError as err:
        raise CloudReadError(f"{path}: {err}") from None
    except MemoryError:
        raise CloudReadError(f"{path}: not enough memory to read this cloud") from None
    except (*_PARSE_ERRORS, OSError) as err:
        raise CloudReadError(f"{path}: not a readable {suffix} cloud ({err})") from None
    if len(points) == 0:
        raise CloudReadError(f"{path}: the cloud has no points")
    return points


def write_ply(path: str | Path, points: NDArray) -> None:
    """Write points (N, 3) as a binary little-endian PLY with float32 x, y, z."""
    pts = np.ascontiguousarray(np.asarray(points, dtype="<f4").reshape(-1, 3))
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment written by itnet\n"
        f"element vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
        "end_header\n"
    )
    Path(path).write_bytes(header.encode("ascii") + pts.tobytes())


def _split_header(data: bytes, end_marker: bytes) -> tuple[list[str], bytes]:
    end = data.find(end_marker, 0, MAX_HEADER_BYTES)
    if end < 0:
        raise CloudReadError(f"no {end_marker.decode().strip()!r} in the first 64 KiB")
    body_start = data.find(b"\n", end) + 1 if data.find(b"\n", end) >= 0 else len(data)
    return data[:end].decode("ascii").splitlines(), data[body_start:]


def _read_ply(data: bytes) -> NDArray[Any]:
    if not data.startswith(b"ply"):
        raise CloudReadError("not a PLY file (no 'ply' magic)")
    lines, body = _split_header(data, b"end_header")
    fmt = ""
    elements: list[tuple[str, int, list[tuple[str, str | None]]]] = []  # name, count, properties
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[-1], None))
            else:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
    if not elements or elements[0][0] != "vertex":
        raise CloudReadError("the first element is not 'vertex'")
    _, count, props = elements[0]
    names = [p for p, _ in props]
    if count < 0 or not {"x", "y", "z"} <= set(names):
        raise CloudReadError("vertex element lacks x, y, z")
    if any(t is None for _, t in props):
        raise CloudReadError("list properties on vertices are not supported")
    if fmt == "ascii":
        table = np.loadtxt(body.decode("ascii").splitlines()[:count], ndmin=2)
        if table.shape != (count, len(props)):
            raise CloudReadError(f"expected {count} vertex rows of {len(props)} values")
        return table[:, [names.index(a) for a in "xyz"]]
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    if order is None:
        raise CloudReadError(f"unknown PLY format {fmt!r}")
    dtype = np.dtype([(n, order + str(t)) for n, t in props])
    if len(body) < count * dtype.itemsize:
        raise CloudReadError(f"truncated: {count} vertices need {count * dtype.itemsize} bytes")
    records: Any = np.frombuffer(body, dtype=dtype, count=count)
    return np.stack([records[a].astype(np.float64) for a in "xyz"], axis=-1)


def _read_pcd(data: bytes) -> NDArray:
    lines, body = _split_header(data, b"DATA")
    header = {}
    for line in lines:
        words = line.split()
        if words and not words[0].startswith("#"):
            header[words[0].upper()] = words[1:]
    data_line = data[data.find(b"DATA") :].split(b"\n", 1)[0].split()
    kind = data_line[1].decode() if len(data_line) > 1 else ""
    fields = header["FIELDS"]
    sizes = [int(s) for s in header["SIZE"]]
    types = header["TYPE"]
    counts = [int(c) for c in header.get("COUNT", ["1"] * len(fields))]
    n = int(header["POINTS"][0]) if "POINTS" in header else int(header["WIDTH"][0])
    if not {"x", "y", "z"} <= set(fields) or n < 0:
        raise CloudReadError("PCD lacks x, y, z fields")
    if not len(fields) == len(sizes) == len(types) == len(counts):
        raise CloudReadError("PCD FIELDS, SIZE, TYPE and COUNT differ in length")
    if min(counts) < 1:
        raise CloudReadError(f"PCD COUNT must be at least 1, got {min(counts)}")
    dtypes = [_pcd_dtype(t, s) for t, s in zip(types, sizes)]
    if kind == "ascii":
        table = np.loadtxt(body.decode("ascii").splitlines()[:n], ndmin=2)
        col = np.cumsum([0, *counts])
        return table[:, [col[fields.index(a)] for a in "xyz"]]
    if kind == "binary":
        dtype = np.dtype([(f, "<" + d, (c,)) for f, d, c in zip(fields, dtypes, counts)])
        if len(body) < n * dtype.itemsize:
            raise CloudReadError(f"truncated: {n} points need {n * dtype.itemsize} bytes")
        records: Any = np.frombuffer(body, dtype=dtype, count=n)
        return np.stack([records[a][:, 0].astype(np.float64) for a in "xyz"], axis=-1)
    if kind == "binary_compressed":
        if len(body) < 8:
            raise CloudReadError("truncated: no compressed-size header after DATA")
        compressed, raw_size = (int(v) for v in np.frombuffer(body[:8], dtype="<u4"))
        point_bytes = sum(c * np.dtype(d).itemsize for d, c in zip(dtypes, counts))
        if raw_size != n * point_bytes:
            raise CloudReadError(f"{n} points need {n * point_bytes} bytes, header says {raw_size}")
        if len(body) < 8 + compressed:
            raise CloudReadError(f"truncated: {compressed} compressed bytes announced")
        raw = _lzf_decompress(body[8 : 8 + compressed], raw_size)
        out, offset = {}, 0  # columns are stored one after the other
        for f, d, c in zip(fields, dtypes, counts):
            nbytes = n * c * np.dtype(d).itemsize
            out[f] = np.frombuffer(raw[offset : offset + nbytes], dtype="<" + d).reshape(n, c)
            offset += nbytes
        return np.stack([out[a][:, 0].astype(np.float64) for a in "xyz"], axis=-1)
    raise CloudReadError(f"unknown PCD DATA kind {kind!r}")


def _pcd_dtype(kind: str, size: int) -> str:
    """PCD TYPE and SIZE (``F``, 4) -> numpy type code (``f4``), or CloudReadError."""
    if kind not in _PCD_KINDS or size not in _PCD_KINDS[kind][1]:
        raise CloudReadError(f"unsupported PCD field type {kind!r} of size {size}")
    return f"{_PCD_KINDS[kind][0]}{size}"


def _lzf_decompress(src: bytes, size: int) -> bytes:
    """LZF (liblzf) decompression, as used by PCD's binary_compressed. Never produces more than
    ``size`` bytes, and refuses a ``size`` that ``src`` cannot possibly hold."""
    if size > LZF_MAX_RATIO * len(src):
        raise CloudReadError(f"{len(src)} compressed bytes cannot hold {size} bytes")
    out = bytearray()
    i = 0
    while i < len(src) and len(out) <= size:
        ctrl = src[i]
        i += 1
        if ctrl < 32:  # literal run of ctrl + 1 bytes
            out += src[i : i + ctrl + 1]
            i += ctrl + 1
            continue
        length = ctrl >> 5
        if length == 7:
            length += src[i]
            i += 1
        ref = len(out) - ((ctrl & 0x1F) << 8) - src[i] - 1
        i += 1
        if ref < 0:
            raise CloudReadError("corrupt compressed PCD data")
        length += 2
        if ref + length <= len(out):  # the usual case: the copy does not overlap its output
            out += out[ref : ref + length]
            continue
        for _ in range(length):  # an overlapping copy repeats the bytes it is writing
            out.append(out[ref])
            ref += 1
    if len(out) != size:
        raise CloudReadError(f"compressed PCD data decodes to {len(out)} bytes, not {size}")
    return bytes(out)


def _read_npy(data: bytes) -> NDArray:
    """A numeric (N, >= 3) .npy array. The header is checked against the file's size before
    anything is allocated: a header that claims 10^12 rows fails at once."""
    import io

    stream = io.BytesIO(data)
    version = np.lib.format.read_magic(stream)
    read_header = {(1, 0): np.lib.format.read_array_header_1_0}.get(
        version, np.lib.format.read_array_header_2_0
    )
    shape, _, dtype = read_header(stream)
    if len(shape) != 2 or shape[1] < 3:
        raise CloudReadError(f"expected an (N, 3) array, got shape {shape}")
    if dtype.kind not in "iuf" or dtype.fields is not None:
        raise CloudReadError(f"expected a numeric array, got dtype {dtype}")
    needed = shape[0] * shape[1] * dtype.itemsize
    if len(data) - stream.tell() < needed:
        raise CloudReadError(f"truncated: an array of shape {shape} needs {needed} bytes")
    arr = np.load(io.BytesIO(data), allow_pickle=False)
    return arr[:, :3]


def _read_text(data: bytes) -> NDArray:
    rows = []
    for line in data.decode("utf-8").splitlines():
        words = line.replace(",", " ").split()
        if len(words) >= 3:
            rows.append([float(w) for w in words[:3]])
        elif words and rows:  # a count line is allowed only before the points (.pts)
            raise CloudReadError(f"a line with fewer than 3 values: {line[:60]!r}")
    return np.asarray(rows).reshape(-1, 3)
