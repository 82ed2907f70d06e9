"""What a batch job works on: files (clouds, depth images) named by paths, folders or globs, and
manifests of pairs.

Pure Python (no Ray): the batch command expands its inputs here, in the driver, before any worker
starts, so a typo fails at once and the job's size is known for the progress bar.
"""

from __future__ import annotations

import csv
import glob
import json
from pathlib import Path

from itnet.cloud_io import SUFFIXES


class InputError(ValueError):
    """An input path, glob or manifest that names nothing usable."""


def expand_inputs(
    inputs: list[str], suffixes: tuple[str, ...] = SUFFIXES, what: str = "cloud files"
) -> list[str]:
    """Files as given, folders -> their files with one of ``suffixes`` (recursive, sorted),
    globs -> their matches.

    A file is kept whatever its suffix (a bad one becomes an error row, not a silent skip); in a
    folder or a glob only files with one of ``suffixes`` (default: the cloud suffixes,
    ``itnet.cloud_io.SUFFIXES``) count. The order is kept and duplicates are dropped. Raises
    InputError for an input matching nothing (``what``: how the message names the files)."""
    found: list[str] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            matches = [str(p) for p in sorted(path.rglob("*")) if _matches(p, suffixes)]
        elif path.exists():
            matches = [item]
        elif glob.has_magic(item):
            matches = [
                p for p in sorted(glob.glob(item, recursive=True)) if _matches(Path(p), suffixes)
            ]
        else:
            raise InputError(f"{item}: no such file or folder")
        if not matches:
            raise InputError(f"{item}: no {what} ({' '.join(suffixes)})")
        found.extend(matches)
    return list(dict.fromkeys(found))


def _matches(path: Path, suffixes: tuple[str, ...]) -> bool:
    return path.is_file() and path.suffix.lower() in suffixes


def read_manifest(path: Path) -> list[tuple[str, str, str, str]]:
    """A manifest of pairs -> [(a, b, up_a, up_b), ...]: CSV with a header naming columns ``a``
    and ``b``, or JSON Lines (``.jsonl``) of objects with keys ``a`` and ``b``. Optional
    ``up_a``, ``up_b``: which way is up in each cloud, 'x,y,z' (JSON Lines: also [x, y, z]),
    given back as 'x,y,z' ('' where absent). Relative paths are taken relative to the
    manifest's folder. Raises InputError saying what is wrong."""
    if not path.is_file():
        raise InputError(f"{path}: no such manifest")
    rows: list[dict[str, str]]
    try:
        if path.suffix.lower() in (".jsonl", ".ndjson"):
            lines = path.read_text().splitlines()
            rows = [json.loads(line) for line in lines if line.strip()]
        else:
            with path.open(newline="") as f:
                rows = list(csv.DictReader(f))
    except (json.JSONDecodeError, csv.Error, UnicodeDecodeError) as err:
        raise InputError(f"{path}: not a CSV or JSON Lines manifest ({err})") from None
    pairs = []
    for number, row in enumerate(rows, start=1):
        if not isinstance(row, dict) or not row.get("a") or not row.get("b"):
            raise InputError(f"{path}: row {number} has no 'a' and 'b' (got {row!r:.80})")
        ups = [_up(path, number, row.get(key)) for key in ("up_a", "up_b")]
        pairs.append((_beside(path, str(row["a"])), _beside(path, str(row["b"])), *ups))
    if not pairs:
        raise InputError(f"{path}: no pairs")
    return list(dict.fromkeys(pairs))


def _up(manifest: Path, number: int, value: object) -> str:
    """A row's up direction -> 'x,y,z' ('' where none); InputError unless it is three finite
    numbers, not all zero."""
    from itnet.request_fields import parse_xyz
    from itnet.upright import unit_up

    if value is None or value == "":
        return ""
    try:
        numbers = parse_xyz(value)  # type: ignore[arg-type]
    except ValueError:
        numbers = []  # not numbers: unit_up says what an up must be
    try:
        unit_up(numbers)
    except ValueError as err:
        raise InputError(f"{manifest}: row {number}: {err} (got {value!r:.60})") from None
    return ",".join(str(v) for v in numbers)


def _beside(manifest: Path, name: str) -> str:
    path = Path(name)
    return name if path.is_absolute() else str(manifest.parent / path)
