"""``graph_digest``: the SHA-256 of an ONNX model file without its metadata, so a file whose card
changed (``itnet card``, ``itnet centre-fit --write``) keeps the digest of the graph it holds.

An ONNX file is a ModelProto: protobuf fields one after another. The digest hashes every
top-level field but ``metadata_props`` (field 14, where the card is), as stored; it reads the
wire format itself, so the runtime needs no ``onnx`` package.
"""

from __future__ import annotations

import hashlib
from functools import lru_cache
from pathlib import Path

METADATA_FIELD = 14  # ModelProto.metadata_props


def _varint(data: bytes, at: int) -> tuple[int, int]:
    """The varint at ``at`` -> (its value, the offset after it); ValueError past the end."""
    value = shift = 0
    while True:
        if at >= len(data):
            raise ValueError("truncated protobuf")
        byte = data[at]
        value |= (byte & 0x7F) << shift
        at, shift = at + 1, shift + 7
        if not byte & 0x80:
            return value, at


def _fields(data: bytes) -> list[tuple[int, bytes]]:
    """The top-level fields of a protobuf message: (field number, the field's bytes as stored)."""
    fields, at = [], 0
    while at < len(data):
        start = at
        tag, at = _varint(data, at)
        wire = tag & 7
        if wire == 0:
            _, at = _varint(data, at)
        elif wire == 1:
            at += 8
        elif wire == 2:
            size, at = _varint(data, at)
            at += size
        elif wire == 5:
            at += 4
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
        if at > len(data):
            raise ValueError("truncated protobuf")
        fields.append((tag >> 3, data[start:at]))
    return fields


def digest_without_metadata(data: bytes) -> str:
    """An ONNX file's bytes -> the SHA-256 (hex) of every top-level field but its metadata."""
    digest = hashlib.sha256()
    for number, raw in _fields(data):
        if number != METADATA_FIELD:
            digest.update(raw)
    return digest.hexdigest()


@lru_cache(maxsize=64)
def _digest(path: Path, size: int, mtime_ns: int) -> str:
    return digest_without_metadata(path.read_bytes())


def graph_digest(path: Path) -> str:
    """The digest of the graph in the ONNX file at ``path`` (its card left out), computed once
    per file version."""
    stat = path.stat()
    return _digest(path.resolve(), stat.st_size, stat.st_mtime_ns)
