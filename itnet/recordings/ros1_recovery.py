"""A ROS 1 bag without a usable index (a recording cut short: the recorder killed, the disk
full, the file copied while written) read in file order, chunk by chunk, up to where it ends,
as ``rosbag reindex`` would recover it, without writing a copy.

``UnindexedRos1Reader`` stands in for rosbags' ROS 1 reader inside its ``AnyReader``, so the
messages deserialise as any bag's do. It uses the record layout of the ROS bag format 2.0
(http://wiki.ros.org/Bags/Format/2.0): each record a header of ``name=value`` fields (``op``
its kind) and a data block; chunks hold connection and message records.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Iterator
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

from rosbags.interfaces import (
    Connection,
    ConnectionExtRosbag1,
    MessageDefinition,
    MessageDefinitionFormat,
)
from rosbags.rosbag1.reader import (
    Header,
    ReaderError,
    RecordType,
    decompressors,
    normalize,
    read_bytes,
    read_uint32,
)
from rosbags.typesys.msg import normalize_msgtype

MAGIC = b"#ROSBAG V2.0\n"


class UnindexedRos1Reader:
    """The readable part of a ROS 1 bag, scanned record by record (one pass when opened for the
    connections and times, one per ``messages`` call); ``end_note`` says where reading stopped
    and why."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.bio: BinaryIO | None = None
        self.connections: list[Connection] = []
        self.chunks: list[tuple[int, str, int]] = []  # (data position, compression, size)
        self.start_time, self.end_time, self.message_count = 2**63 - 1, 0, 0
        self.end_note = ""

    def __enter__(self) -> UnindexedRos1Reader:
        self.open()
        return self

    def __exit__(self, *_: object) -> None:
        self.close()

    def open(self) -> None:
        self.bio = self.path.open("rb")
        if self.bio.readline() != MAGIC:
            raise ReaderError("not a ROS bag of format 2.0")
        found: dict[int, Connection] = {}
        counts: dict[int, int] = {}
        for position, compression, size in self._chunk_records():
            self.chunks.append((position, compression, size))
            for header, data in self._chunk(position, compression, size):
                op = header.get_uint8("op")
                if op == RecordType.CONNECTION and header.get_uint32("conn") not in found:
                    connection = self._connection(header, data)
                    found[connection.id] = connection
                elif op == RecordType.MSGDATA:
                    time = header.get_time("time")
                    conn = header.get_uint32("conn")
                    counts[conn] = counts.get(conn, 0) + 1
                    self.start_time = min(self.start_time, time)
                    self.end_time = max(self.end_time, time + 1)
        self.connections = [
            Connection(c.id, c.topic, c.msgtype, c.msgdef, c.digest, counts.get(c.id, 0), c.ext, self)
            for c in found.values()
        ]  # fmt: skip
        self.message_count = sum(counts.values())
        if not self.message_count:
            self.start_time = self.end_time = 0

    def close(self) -> None:
        if self.bio is not None:
            self.bio.close()
            self.bio = None

    @property
    def duration(self) -> int:
        return self.end_time - self.start_time

    @property
    def topics(self) -> dict[str, Any]:
        return {}

    def messages(self, connections: Collection[Connection] = (), start: int | None = None,
                 stop: int | None = None) -> Iterator[tuple[Connection, int, bytes]]:  # fmt: skip
        """(connection, log time ns, raw data) of the wanted connections, chunk by chunk, each
        chunk's in time order."""
        wanted = {c.id: c for c in (connections or self.connections)}
        for position, compression, size in self.chunks:
            found = []
            for header, data in self._chunk(position, compression, size):
                if header.get_uint8("op") != RecordType.MSGDATA:
                    continue
                connection = wanted.get(header.get_uint32("conn"))
                time = header.get_time("time")
                if connection is None or (start is not None and time < start):
                    continue
                if stop is not None and time >= stop:
                    continue
                found.append((connection, time, data))
            found.sort(key=lambda m: m[1])
            yield from found

    def _chunk_records(self) -> Iterator[tuple[int, str, int]]:
        """(data position, compression, size) of every whole chunk, in file order."""
        assert self.bio is not None
        bio = self.bio
        total = os.fstat(bio.fileno()).st_size
        try:
            header = Header.read(bio, RecordType.BAGHEADER)
            bio.seek(read_uint32(bio), os.SEEK_CUR)
            del header
            while bio.tell() < total:
                header = Header.read(bio)
                size = read_uint32(bio)
                position = bio.tell()
                if position + size > total:
                    self.end_note = f"its last record is cut off at byte {total}"
                    return
                bio.seek(size, os.SEEK_CUR)
                if header.get_uint8("op") == RecordType.CHUNK:
                    yield position, header.get_string("compression"), size
        except ReaderError as err:
            self.end_note = f"unreadable from byte {bio.tell()}: {err}"

    def _chunk(self, position: int, compression: str, size: int) -> Iterator[tuple[Header, bytes]]:
        """The (header, data) records inside one chunk."""
        assert self.bio is not None
        self.bio.seek(position)
        try:
            inner = BytesIO(decompressors[compression](read_bytes(self.bio, size)))
        except (KeyError, OSError, ValueError, RuntimeError, ReaderError):
            return  # a chunk whose data does not decompress holds nothing to read
        end = len(inner.getbuffer())
        while inner.tell() < end:
            try:
                header = Header.read(inner)
                data = read_bytes(inner, read_uint32(inner))
            except ReaderError:
                return
            yield header, data

    def _connection(self, header: Header, data: bytes) -> Connection:
        fields = Header.read(BytesIO(len(data).to_bytes(4, "little") + data))
        latching = fields.get_string("latching") if "latching" in fields else None
        return Connection(
            header.get_uint32("conn"),
            normalize(header.get_string("topic")),
            normalize_msgtype(fields.get_string("type")),
            MessageDefinition(MessageDefinitionFormat.MSG, fields.get_string("message_definition")),
            fields.get_string("md5sum"),
            0,
            ConnectionExtRosbag1(
                fields.get_string("callerid") if "callerid" in fields else None,
                int(latching) if latching else None,
            ),
            self,
        )
