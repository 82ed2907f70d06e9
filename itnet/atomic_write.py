"""Files that appear whole or not at all: written under a hidden temporary name beside their
target, then renamed onto it (a rename within one folder is atomic). A reader in another
process (a cache shared by parallel training jobs, a resumable batch's parts, a checkpoint read
while the next one is written) never opens half a file; a write that fails leaves none."""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def written_whole(path: Path) -> Iterator[Path]:
    """Yields the path to write ``path``'s content to (hidden, this process's own); when the
    block ends it is renamed onto ``path``, and when the block raises it is removed."""
    partial = path.with_name(f".{path.name}.{os.getpid()}.partial")
    try:
        yield partial
    except BaseException:
        partial.unlink(missing_ok=True)
        raise
    os.replace(partial, path)
