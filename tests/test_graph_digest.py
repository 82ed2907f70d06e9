"""A model's graph digest ignores its card: a card edit keeps what was fitted for the graph."""

from __future__ import annotations

import hashlib
import shutil

import onnx
import pytest
from onnx import numpy_helper

from itnet.graph_digest import digest_without_metadata, graph_digest
from itnet.pose.runtime import default_model_dir


def test_the_digest_follows_the_graph_and_not_the_card(tmp_path):
    path = tmp_path / "chair.onnx"
    shutil.copy(default_model_dir() / "chair.onnx", path)
    before = graph_digest(path)
    model = onnx.load(str(path))
    card = next(entry for entry in model.metadata_props if entry.key == "itnet")
    card.value = card.value.replace('"chair"', '"CHAIR"')
    edited = model.SerializeToString()
    assert hashlib.sha256(edited).hexdigest() != hashlib.sha256(path.read_bytes()).hexdigest()
    assert digest_without_metadata(edited) == before
    first = model.graph.initializer[0]
    changed = numpy_helper.to_array(first).copy()
    changed.flat[0] += 1
    first.CopyFrom(numpy_helper.from_array(changed, first.name))
    assert digest_without_metadata(model.SerializeToString()) != before


def test_a_truncated_file_is_refused():
    data = (default_model_dir() / "chair.onnx").read_bytes()
    with pytest.raises(ValueError, match="truncated"):
        digest_without_metadata(data[:-7])
