"""The batch output: one table (Parquet, or JSON Lines by the suffix), written so a job can resume.

While a job runs, every finished batch of rows goes to its own file in ``<output>.parts/``; at the
end the parts (and the rows of an earlier ``<output>``, if any) are merged into ``<output>``
(written aside, then renamed) and the parts folder is removed. A job that stopped half-way
(Ctrl-C, a crash, a lost node) leaves its parts; run the same command again and it skips every
input already in ``<output>`` or in a part. Error rows count as done: delete ``<output>`` (or its
rows) to try those again.
"""

from __future__ import annotations

import json
import shutil
import uuid
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from itnet.atomic_write import written_whole

FORMATS = {".parquet": "parquet", ".jsonl": "jsonl", ".ndjson": "jsonl"}


class OutputError(ValueError):
    """An output path the batch cannot write to."""


class BatchTable:
    """The rows of one job, keyed by ``key`` (a column, or a tuple of columns for pairs)."""

    def __init__(self, output: Path, key: tuple[str, ...]) -> None:
        self.format = FORMATS.get(output.suffix.lower(), "")
        if not self.format:
            raise OutputError(f"{output}: the output must end in {', '.join(FORMATS)}")
        if output.is_dir():
            raise OutputError(f"{output} is a folder; name a file")
        self.output, self.key = output, key
        self.parts = output.with_name(output.name + ".parts")

    def _sources(self) -> list[Path]:
        parts = (
            sorted(self.parts.glob(f"part-*{self.output.suffix}")) if self.parts.is_dir() else []
        )
        return ([self.output] if self.output.is_file() else []) + parts

    def done(self) -> set[tuple[str, ...]]:
        """The keys of every row already written (earlier output and parts)."""
        keys: set[tuple[str, ...]] = set()
        for source in self._sources():
            for row in _read(source, self.format, columns=list(self.key)):
                keys.add(tuple(str(row[k]) for k in self.key))
        return keys

    def write_part(self, rows: list[dict[str, Any]]) -> Path:
        """One finished batch of rows, on disk at once (written aside, then renamed)."""
        self.parts.mkdir(parents=True, exist_ok=True)
        path = self.parts / f"part-{uuid.uuid4().hex}{self.output.suffix}"
        with written_whole(path) as tmp:
            _write(tmp, self.format, rows)
        return path

    def finish(self) -> int:
        """Merge everything into ``output``, drop the parts; the number of rows."""
        rows = [row for source in self._sources() for row in _read(source, self.format)]
        with written_whole(self.output) as tmp:
            _write(tmp, self.format, rows)
        shutil.rmtree(self.parts, ignore_errors=True)
        return len(rows)


def _write(path: Path, fmt: str, rows: list[dict[str, Any]]) -> None:
    if fmt == "jsonl":
        path.write_text("".join(json.dumps(row) + "\n" for row in rows))
    else:
        # from_pylist takes its columns from the first row: give every row every column.
        columns = list(dict.fromkeys(k for row in rows for k in row if k != "error"))
        columns += ["error"] if any("error" in row for row in rows) else []
        pq.write_table(
            pa.Table.from_pylist([{k: row.get(k) for k in columns} for row in rows]), path
        )


def _read(path: Path, fmt: str, columns: list[str] | None = None) -> Iterable[dict[str, Any]]:
    if fmt == "jsonl":
        with path.open() as f:
            return [json.loads(line) for line in f if line.strip()]
    try:
        table = pq.read_table(path, columns=columns)
    except (pa.ArrowInvalid, KeyError) as err:
        raise OutputError(f"{path}: cannot read it as this job's output ({err})") from None
    return _without_nulls(table.to_pylist())


def _without_nulls(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Parquet gives every row every column (absent: None); rows keep only their own fields, so
    that parts whose columns differ (a part of error rows only) merge into one table."""
    return [{k: v for k, v in row.items() if v is not None} for row in rows]
