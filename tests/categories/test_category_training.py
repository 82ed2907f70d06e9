"""One network for several categories: symmetry-aware training, per-category validation,
evaluation and export of one model per category (tiny synthetic data, seconds)."""

import json

import numpy as np
import pytest
from modelnet_tree import write_modelnet_tree
from typer.testing import CliRunner

from itnet.cli import app


def _chair_like(rng, n=300):
    seat = rng.uniform([-0.5, -0.05, -0.5], [0.5, 0.05, 0.5], size=(n // 2, 3))
    back = rng.uniform([-0.5, 0.05, 0.4], [0.5, 0.9, 0.5], size=(n - n // 2, 3))
    return np.concatenate([seat, back]) * rng.uniform(0.8, 1.2, size=3)


def _bench_like(rng, n=300):  # long along x, front and back alike
    return rng.uniform([-0.9, -0.2, -0.3], [0.9, 0.2, 0.3], size=(n, 3)) * rng.uniform(0.9, 1.1, 3)


@pytest.fixture(scope="module")
def two_categories(tmp_path_factory):
    rng = np.random.default_rng(0)
    root = tmp_path_factory.mktemp("categories")
    return write_modelnet_tree(root, {"seat": _chair_like, "bench": _bench_like}, rng, 10, 3)


@pytest.mark.train
def test_one_network_for_two_categories_with_their_symmetries(two_categories, tmp_path):
    runner = CliRunner()
    run, cache = tmp_path / "run", tmp_path / "cache"
    common = ["--data", str(two_categories), "--frame", "canonical", "--cache", str(cache)]
    result = runner.invoke(
        app,
        ["train", *common, "--no-check-orientation", "--category", "seat,bench", "--out", str(run), "--steps", "6",
         "--batch", "8", "--points", "64", "--iterations", "2", "--eval-every", "3",
         "--threads", "1", "--no-compile"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    lines = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    start = lines[0]
    assert start["symmetry"] == {"seat": "none", "bench": "none"}  # unknown names: no symmetry
    val = [line for line in lines if line.get("event") == "val"]
    assert set(val[-1]["val_categories"]) == {"seat", "bench"}

    # A network of several categories is exported (and evaluated) once per category.
    out = tmp_path / "bench.onnx"
    refused = runner.invoke(app, ["export", str(run / "last.pt"), "--out", str(out)])
    assert refused.exit_code != 0 and "--category" in refused.output
    result = runner.invoke(
        app, ["export", str(run / "last.pt"), "--out", str(out), "--category", "bench"]
    )
    assert result.exit_code == 0, result.output
    from itnet.pose.runtime import load_model

    card = load_model(out, warm_up=False).card
    assert (card.name, card.category, card.symmetry) == ("bench", "bench", "none")
    assert card.training["categories"] == "seat,bench"

    def evaluated(folder: str) -> dict:
        result = runner.invoke(
            app,
            ["eval", "--onnx", str(out), *common, "--no-check-orientation", "--views", "2",
             "--iterations", "2", "--out", str(tmp_path / folder)],
        )  # fmt: skip
        assert result.exit_code == 0, result.output
        return json.loads((tmp_path / folder / "report.json").read_text())  # type: ignore[no-any-return]

    report = evaluated("eval")
    assert (report["category"], report["symmetry"]) == ("bench", "none")
    assert "up_error_deg" not in report  # measured without up

    # A model served only with up is measured only with it (2 degrees off the truth).
    import onnx

    from itnet.export.onnx_export import save_with_card

    save_with_card(onnx.load(str(out)), card.model_copy(update={"requires_up": True}), out)
    assert evaluated("eval-up")["up_error_deg"] == 2.0


@pytest.mark.train
def test_a_users_category_trains_with_the_symmetry_it_is_given(two_categories, tmp_path):
    runner = CliRunner()
    run = tmp_path / "run"
    result = runner.invoke(
        app,
        ["train", "--data", str(two_categories), "--frame", "canonical", "--category", "bench",
         "--symmetry", "yaw180", "--cache", str(tmp_path / "cache"), "--out", str(run),
         "--steps", "2", "--batch", "4", "--points", "32", "--iterations", "1",
         "--eval-every", "2", "--threads", "1", "--no-compile"],
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    start = json.loads((run / "log.jsonl").read_text().splitlines()[0])
    assert start["symmetry"] == {"bench": "yaw180"}
    result = runner.invoke(app, ["export", str(run / "last.pt"), "--out", str(tmp_path / "b.onnx")])
    assert result.exit_code == 0, result.output
    from itnet.pose.runtime import load_model

    card = load_model(tmp_path / "b.onnx", warm_up=False).card
    assert (card.name, card.symmetry) == ("bench", "yaw180")
    bad = runner.invoke(app, ["train", "--category", "bench", "--symmetry", "c3"])
    assert bad.exit_code != 0 and "--symmetry" in bad.output


def test_a_category_left_empty_by_the_orientation_check_says_what_to_do(
    two_categories, tmp_path, monkeypatch
):
    import itnet.model.category_set as category_set
    from itnet.model.scanner import scan_config

    counts = {"loaded": 10, "kept": 0, "turned": 0, "dropped": 10}
    monkeypatch.setattr(category_set, "load_shapes", lambda *a, **k: ([], counts))
    with pytest.raises(ValueError, match="--symmetry yaw180"):
        category_set.load_category_set(
            two_categories, ["bench"], "canonical", tmp_path, True, 0.2, 0, 1, scan_config()
        )


def test_benchmarks_see_the_validation_scans_training_chose_on(two_categories, tmp_path):
    from itnet.model.categories import category
    from itnet.model.category_set import load_category_set, validation_scans
    from itnet.model.scanner import PAPER_VIEWS, scan_config

    cache, scan = tmp_path / "cache", scan_config(PAPER_VIEWS)
    run = load_category_set(
        two_categories, ["seat", "bench"], "canonical", cache, False, 0.3, 5, 2, scan
    )
    for name in ("seat", "bench"):
        alone = validation_scans(
            two_categories, category(name), 2, 5, scan, cache, "canonical", False, 0.3
        )
        assert alone.names == run.validation[name].names and len(alone.names) == 2 * 3
        for a, b in zip(alone.clouds, run.validation[name].clouds):
            assert np.array_equal(a, b)
        assert np.array_equal(alone.poses, run.validation[name].poses)
    seat = validation_scans(
        two_categories, category("seat"), 2, 5, scan, cache, "canonical", False, 0.3
    )
    reseeded = validation_scans(
        two_categories, category("seat"), 2, 6, scan, cache, "canonical", False, 0.3
    )
    assert not all(np.array_equal(a, b) for a, b in zip(reseeded.clouds, seat.clouds))
