"""Category frames and symmetries: measured from shapes, honoured by the orientation check."""

import numpy as np
import pytest

from itnet.model.categories import MODELNET10, category, decide_symmetry, self_match_ratios
from itnet.model.shapes import Shape, check_yaw, yaw_rotation


def _box(rng, size, n=600):
    return rng.uniform(-np.asarray(size), np.asarray(size), size=(n, 3))


def _chair_like(rng, n=600):
    seat = rng.uniform([-0.5, -0.05, -0.5], [0.5, 0.05, 0.5], size=(n // 2, 3))
    back = rng.uniform([-0.5, 0.05, 0.4], [0.5, 0.9, 0.5], size=(n - n // 2, 3))
    return np.concatenate([seat, back])


def _surface_of_cylinder(rng, n=600):
    angle, height = rng.uniform(0, 2 * np.pi, n), rng.uniform(-0.5, 0.5, n)
    return np.stack([0.6 * np.cos(angle), height, 0.6 * np.sin(angle)], 1)


def _shapes(make, rng, count=8):
    return [Shape(f"s{i}", make(rng)) for i in range(count)]


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (_chair_like, "none"),
        (lambda r: _box(r, [0.9, 0.3, 0.4]), "yaw180"),  # long along x, unlike front and side
        (lambda r: _box(r, [0.6, 0.3, 0.6]), "yaw90"),  # square footprint
        (_surface_of_cylinder, "yaw"),
    ],
)
def test_symmetry_is_decided_from_how_shapes_match_themselves_turned(make, expected):
    rng = np.random.default_rng(0)
    ratios = self_match_ratios(_shapes(make, rng), rng)
    assert decide_symmetry(ratios) == expected, ratios


def test_modelnet10_table_covers_every_class_with_a_known_symmetry():
    assert sorted(MODELNET10) == sorted(
        ["bathtub", "bed", "chair", "desk", "dresser", "monitor", "night_stand", "sofa", "table",
         "toilet"]
    )  # fmt: skip
    assert category("chair").symmetry == "none" and category("table").symmetry == "yaw180"
    mug = category("mug", "yaw")  # a user's category: no turn, the symmetry given
    assert (mug.quarter_turns, mug.symmetry) == (0, "yaw")
    assert category("mug").symmetry == "none"
    with pytest.raises(ValueError, match="unknown symmetry"):
        category("mug", "c3")


def test_orientation_check_under_yaw180_turns_back_quarter_turns_and_keeps_half_turns():
    rng = np.random.default_rng(3)
    shapes = _shapes(lambda r: _box(r, [0.9, 0.3, 0.4]) * r.uniform(0.9, 1.1, 3), rng, 12)
    quarter = Shape("q", shapes[2].points @ yaw_rotation(1).T)
    half = Shape("h", shapes[4].points @ yaw_rotation(2).T)
    shapes[2], shapes[4] = quarter, half
    kept, counts = check_yaw(shapes, references=8, sample=128, symmetry="yaw180")
    assert counts == {"kept": 11, "turned": 1, "dropped": 0}
    # the quarter-turned box is put back with its long axis along x
    extent = kept[2].points.max(0) - kept[2].points.min(0)
    assert extent[0] > 1.5 * extent[2]
    # the half-turned one is the same pose under yaw180: left alone
    assert np.allclose(kept[4].points, half.points)
    # under the plain check (no symmetry) a half turn is never clearly better than no turn: the
    # half-turned box is kept or dropped, never "turned back"
    plain_kept, _ = check_yaw(shapes, references=8, sample=128)
    assert not any("turned 180" in note for shape in plain_kept for note in shape.notes)


def test_orientation_check_leaves_yaw90_shapes_alone():
    rng = np.random.default_rng(4)
    shapes = _shapes(lambda r: _box(r, [0.6, 0.3, 0.6]), rng, 6)
    kept, counts = check_yaw(shapes, symmetry="yaw90")
    assert counts == {"kept": 6, "turned": 0, "dropped": 0} and kept == shapes


def test_the_measurement_command_decides_a_users_category(tmp_path):
    from typer.testing import CliRunner

    from itnet.cli import app

    rng = np.random.default_rng(5)
    for split, count in (("train", 6), ("test", 2)):
        folder = tmp_path / "mug" / split
        folder.mkdir(parents=True)
        for i in range(count):
            angle, height = rng.uniform(0, 2 * np.pi, 1000), rng.uniform(-0.5, 0.5, 1000)
            can = np.stack([0.6 * np.cos(angle), height, 0.6 * np.sin(angle)], 1)
            np.save(folder / f"mug_{i}.npy", can)
    result = CliRunner().invoke(app, ["fit", "categories", "--data", str(tmp_path),
                                      "--category", "mug", "--frame", "canonical"])  # fmt: skip
    assert result.exit_code == 0, result.output
    row = next(line for line in result.stdout.splitlines() if line.startswith("| mug"))
    assert row.split("|")[5].strip() == "yaw"  # measured
    assert row.split("|")[6].strip() == "none"  # declared: unknown until given with --symmetry


def test_each_shipped_cards_symmetry_and_up_are_its_categorys():
    """The registry is the one table: every shipped pose model's card says what its category
    says (symmetry, mirror planes, whether up is required)."""
    from itnet.pose.runtime import default_model_dir, load_any

    for name, cat in MODELNET10.items():
        card = load_any(default_model_dir() / f"{name}.onnx", warm_up=False).card
        assert card.category == name
        assert (card.symmetry, card.requires_up) == (cat.symmetry, cat.requires_up), name
        assert tuple(card.mirror_planes) == cat.mirror_planes, name
