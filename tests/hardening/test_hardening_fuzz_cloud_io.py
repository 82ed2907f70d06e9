"""Fuzzing the CLI's cloud readers: whatever the bytes, ``read_cloud`` returns an (N, 3) cloud or
raises ``CloudReadError`` (never another exception), fast, and in memory bounded by the file."""

from __future__ import annotations

import io
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from hardening_helpers import scaled
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from itnet.cloud_io import CloudReadError, read_cloud

POINTS = np.random.default_rng(5).normal(size=(40, 3)).astype(np.float32)
XYZ = "property float x\nproperty float y\nproperty float z\n"
PCD_HEAD = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH {n}\nHEIGHT 1\n"
MAX_SECONDS, MAX_PEAK_BYTES = 2.0, 32 * 2**20
FUZZ = settings(max_examples=scaled(150), deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip


def lzf_compress(data: bytes) -> bytes:
    """A plain greedy LZF compressor (literal runs and back-references, overlapping ones too)."""
    out, literal, table, i = bytearray(), bytearray(), {}, 0

    def flush() -> None:
        while literal:
            out.append(min(32, len(literal)) - 1)
            out.extend(literal[:32])
            del literal[:32]

    while i < len(data):
        key = data[i : i + 3]
        ref = table.get(key) if len(key) == 3 else None
        table[key] = i
        if ref is None or i - ref - 1 >= 8192:
            literal.append(data[i])
            i += 1
            continue
        length = 3
        while length < min(264, len(data) - i) and data[ref + length] == data[i + length]:
            length += 1
        flush()
        offset, code = i - ref - 1, length - 2
        out.append((min(code, 7) << 5) | (offset >> 8))
        if code >= 7:
            out.append(code - 7)
        out.append(offset & 0xFF)
        i += length
    flush()
    return bytes(out)


def npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return buffer.getvalue()


def compressed_pcd(points: np.ndarray) -> bytes:
    raw = np.ascontiguousarray(points.astype("<f4").T).tobytes()  # columns one after another
    packed = lzf_compress(raw)
    head = PCD_HEAD.format(n=len(points)) + f"POINTS {len(points)}\nDATA binary_compressed\n"
    return head.encode() + np.array([len(packed), len(raw)], "<u4").tobytes() + packed


SEEDS: dict[str, bytes] = {
    ".ply": (f"ply\nformat binary_little_endian 1.0\nelement vertex 40\n{XYZ}end_header\n".encode()
             + POINTS.astype("<f4").tobytes()),
    ".xyz": "\n".join(" ".join(f"{v:.5f}" for v in p) for p in POINTS).encode(),
    ".npy": npy_bytes(POINTS),
    ".pcd": compressed_pcd(POINTS),
}  # fmt: skip
ASCII_PLY = (f"ply\nformat ascii 1.0\nelement vertex 40\n{XYZ}end_header\n" + SEEDS[".xyz"].decode()).encode()  # fmt: skip
ASCII_PCD = (PCD_HEAD.format(n=40) + "POINTS 40\nDATA ascii\n" + SEEDS[".xyz"].decode()).encode()
BINARY_PCD = (PCD_HEAD.format(n=40) + "POINTS 40\nDATA binary\n").encode() + POINTS.tobytes()
VARIANTS = [(".ply", SEEDS[".ply"]), (".ply", ASCII_PLY), (".pcd", SEEDS[".pcd"]),
            (".pcd", ASCII_PCD), (".pcd", BINARY_PCD), (".xyz", SEEDS[".xyz"]),
            (".npy", SEEDS[".npy"])]  # fmt: skip


def read_checked(path: Path, data: bytes) -> np.ndarray | CloudReadError:
    """read_cloud on ``data``: the cloud, or the CloudReadError (which must name the file). Fails
    on any other exception, on a slow read, or on a read that allocates far beyond the file."""
    path.write_bytes(data)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        cloud: np.ndarray | CloudReadError = read_cloud(path)
    except CloudReadError as err:
        assert path.name in str(err)
        cloud = err
    finally:
        seconds = time.perf_counter() - start
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    assert seconds < MAX_SECONDS, f"{seconds:.1f} s for {len(data)} bytes"
    assert peak < MAX_PEAK_BYTES + 100 * len(data), f"{peak} bytes allocated for {len(data)}"
    if isinstance(cloud, np.ndarray):
        assert cloud.ndim == 2 and cloud.shape[1] == 3 and len(cloud) > 0
        assert cloud.dtype == np.float64
    return cloud


@pytest.mark.parametrize(("suffix", "data"), VARIANTS)
def test_the_seed_files_read_back(tmp_path: Path, suffix: str, data: bytes) -> None:
    cloud = read_checked(tmp_path / f"seed{suffix}", data)
    assert isinstance(cloud, np.ndarray), cloud
    np.testing.assert_allclose(cloud, POINTS, atol=1e-4)


@FUZZ
@given(variant=st.sampled_from(VARIANTS), cut=st.floats(0, 1))
def test_truncated_files(tmp_path: Path, variant: tuple[str, bytes], cut: float) -> None:
    suffix, data = variant
    read_checked(tmp_path / f"t{suffix}", data[: int(len(data) * cut)])


@FUZZ
@given(variant=st.sampled_from(VARIANTS), edits=st.lists(
    st.tuples(st.floats(0, 1), st.integers(0, 255)), min_size=1, max_size=8))  # fmt: skip
def test_corrupted_bytes(
    tmp_path: Path, variant: tuple[str, bytes], edits: list[tuple[float, int]]
) -> None:
    suffix, data = variant
    corrupt = bytearray(data)
    for where, value in edits:
        corrupt[min(int(where * len(data)), len(data) - 1)] = value
    read_checked(tmp_path / f"c{suffix}", bytes(corrupt))


HEADER_NUMBERS = st.one_of(st.integers(-(2**70), 2**70).map(str), st.sampled_from(
    ["0", "-1", "1e12", "nan", "", "4294967295", "99999999999999999999", "3", "x"]))  # fmt: skip


@FUZZ
@given(variant=st.sampled_from(VARIANTS[:5]), which=st.integers(0, 30), number=HEADER_NUMBERS)
def test_header_numbers_replaced(
    tmp_path: Path, variant: tuple[str, bytes], which: int, number: str
) -> None:
    """Any number in the header (counts, sizes, lengths) replaced by a huge, negative or
    malformed one."""
    suffix, data = variant
    end = data.find(b"end_header") if suffix == ".ply" else data.find(b"DATA")
    head, body = data[:end].decode(), data[end:]
    words = head.replace("\n", " \n ").split(" ")
    digits = [i for i, w in enumerate(words) if w.strip().lstrip("-").isdigit()]
    words[digits[which % len(digits)]] = number
    read_checked(tmp_path / f"h{suffix}", " ".join(words).replace(" \n ", "\n").encode() + body)


@FUZZ
@given(suffix=st.sampled_from([".ply", ".pcd", ".xyz", ".npy"]), data=st.binary(max_size=3000),
       magic=st.sampled_from([b"", b"ply\n", b"\x93NUMPY\x01\x00", b"FIELDS x y z\n"]))  # fmt: skip
def test_random_bytes(tmp_path: Path, suffix: str, data: bytes, magic: bytes) -> None:
    read_checked(tmp_path / f"r{suffix}", magic + data)


def npy_claiming(shape: str, descr: str = "<f8") -> bytes:
    header = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}"
    header += " " * (117 - len(header)) + "\n"
    return b"\x93NUMPY\x01\x00" + len(header).to_bytes(2, "little") + header.encode() + bytes(96)


def pcd_with(size: str = "4 4 4", count: str = "1 1 1", points: str = "40", kind: str = "binary",
             body: bytes = POINTS.tobytes()) -> bytes:  # fmt: skip
    head = (f"FIELDS x y z\nSIZE {size}\nTYPE F F F\nCOUNT {count}\nWIDTH 40\nPOINTS {points}\n"
            f"DATA {kind}\n")  # fmt: skip
    return head.encode() + body


BOMB = lzf_compress(bytes(2**20))  # 1 MiB of zeros in a few KiB
TERA = b"1000000000000"


def lzf_body(packed: bytes, raw_size: int) -> bytes:
    return np.array([len(packed), raw_size], "<u4").tobytes() + packed


HOSTILE: dict[str, tuple[str, bytes, str]] = {
    "ply claims 10^12 vertices": (
        ".ply", SEEDS[".ply"].replace(b"vertex 40", b"vertex " + TERA), "truncated"),
    "ascii ply claims 10^12": (
        ".ply", ASCII_PLY.replace(b"vertex 40", b"vertex " + TERA), "expected"),
    "pcd claims 10^12 points": (
        ".pcd", BINARY_PCD.replace(b"POINTS 40", b"POINTS " + TERA), "truncated"),
    "npy claims 10^12 rows": (".npy", npy_claiming("(1000000000000, 3)"), "truncated"),
    "npy of strings": (".npy", npy_bytes(np.array([["a", "b", "c"]] * 4)), "numeric"),
    "npy of records": (".npy", npy_bytes(np.zeros((4, 3), dtype=[("a", "<f4")])), "numeric"),
    "npy of dates": (".npy", npy_bytes(np.zeros((4, 3), dtype="M8[s]")), "numeric"),
    "pcd float of 3 bytes": (".pcd", pcd_with(size="3 4 4"), "size 3"),
    "pcd count -1": (".pcd", pcd_with(count="-1 1 1"), "COUNT"),
    "pcd fields and sizes differ": (".pcd", pcd_with(size="4 4"), "differ in length"),
    "lzf claims 4 GiB": (".pcd", pcd_with(
        kind="binary_compressed", body=lzf_body(BOMB, 2**32 - 1)), "header says"),
    "lzf bomb": (".pcd", pcd_with(
        points=str(2**20 // 12), kind="binary_compressed", body=lzf_body(BOMB[:60], 2**20 // 12 * 12)),
        "cannot hold"),
}  # fmt: skip


@pytest.mark.parametrize(("suffix", "data", "words"), HOSTILE.values(), ids=list(HOSTILE))
def test_hostile_files_fail_fast_with_a_clear_error(
    tmp_path: Path, suffix: str, data: bytes, words: str
) -> None:
    """Regressions: a PCD SIZE of 3 (TypeError), a .npy claiming 10^12 rows (MemoryError) or
    holding strings (ValueError) escaped as other exceptions; a PCD could claim 4 GiB of LZF
    output and get a byte-by-byte Python loop toward it."""
    error = read_checked(tmp_path / f"hostile{suffix}", data)
    assert isinstance(error, CloudReadError) and words in str(error), error


@pytest.mark.parametrize("make", [lambda: bytes(50_000), lambda: np.random.default_rng(0).bytes(
    50_000), lambda: np.tile(np.arange(7, dtype=np.uint8), 9000).tobytes()])  # fmt: skip
def test_lzf_round_trip_including_overlapping_copies(
    tmp_path: Path, make: Callable[[], bytes]
) -> None:
    raw = make()
    points = np.frombuffer(raw[: len(raw) // 12 * 12], dtype="<f4").reshape(-1, 3)
    points = np.nan_to_num(points)
    cloud = read_checked(tmp_path / "lzf.pcd", compressed_pcd(points))
    assert isinstance(cloud, np.ndarray), cloud
    np.testing.assert_array_equal(cloud, points.astype(np.float64))
