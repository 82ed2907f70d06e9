"""The large-JSON parser's worker process: ``python -m itnet.service.guards.parse_worker``.

It reads requests from stdin and writes replies to stdout, one at a time, until stdin closes.

* request: a header line ``<body bytes> <text: 0|1> <max_points> <schema>\\n``, then the body
  (UTF-8; ``text`` 1: it was a str, a WebSocket message, and is parsed as one);
* reply: a header line ``ok <cloud bytes>\\n`` followed by the cloud (float64, N x 3, row-major)
  and one line of JSON (the request's other fields), or ``error <status> <kind>\\n`` followed by
  one line, the error's detail.

The checks are the server's own (``decode.count_points``, then ``decode.decode_json``), so a bad
body gets the same 4xx whichever process parses it. Only the server talks to this process.
"""

from __future__ import annotations

import json
import signal
import sys
from typing import BinaryIO

import numpy as np

from itnet.service import schemas
from itnet.service.decode import count_points, decode_json
from itnet.service.errors import ServiceError
from itnet.service.heap import return_freed_memory

SCHEMAS = {"EstimateRequest": schemas.EstimateRequest, "StreamRequest": schemas.StreamRequest}


def serve_one(source: BinaryIO, sink: BinaryIO) -> bool:
    """Answer one request; False when the server closed the pipe."""
    header = source.readline()
    if not header:
        return False
    size, text, max_points, schema = header.split()
    raw = source.read(int(size))
    body: bytes | str = raw.decode("utf-8") if text == b"1" else raw
    del raw
    try:
        count_points(body, int(max_points))
        points, request = decode_json(body, SCHEMAS[schema.decode()])
        del body
        cloud = np.ascontiguousarray(points, dtype="<f8").tobytes()
        fields = json.dumps(request.model_dump(exclude={"points"})).encode()
        del points, request
        sink.write(b"ok %d\n" % len(cloud))
        sink.write(cloud)
        sink.write(fields + b"\n")
    except ServiceError as err:
        sink.write(f"error {err.status} {err.kind}\n".encode())
        sink.write(json.dumps(err.detail).encode() + b"\n")
    sink.flush()
    return_freed_memory()
    return True


def main() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the group: the server stops us
    while serve_one(sys.stdin.buffer, sys.stdout.buffer):
        pass


if __name__ == "__main__":
    main()
