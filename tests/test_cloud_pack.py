"""model/cloud_pack.py: clouds on a 16-bit grid over their own box, Morton-sorted and delta-coded;
a pack of a ModelNet-style tree unpacks to the same layout and the same clouds, up to the grid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from itnet.cloud_io import write_ply
from itnet.model.cloud_pack import LEVELS, decode, encode, pack, unpack
from itnet.model.data import split_files

TOLERANCE = 1e-4  # of the box's longest side


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance from a point of either set to its nearest neighbour in the other."""
    return max(cKDTree(b).query(a)[0].max(), cKDTree(a).query(b)[0].max())


def _side(points: np.ndarray) -> float:
    side = float(np.ptp(points, axis=0).max())
    return side if side > 0 else 1.0


def _spread(rng: np.random.Generator, n: int, low: float, high: float) -> np.ndarray:
    """Random points at least ~1e-3 of the box apart, so that nearest neighbours pair them."""
    grid = rng.choice(1000**3, size=n, replace=False)
    cells = np.stack(np.unravel_index(grid, (1000, 1000, 1000)), axis=1)
    return low + (cells + rng.uniform(0.25, 0.75, size=(n, 3))) / 1000 * (high - low)


def _clouds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    flat = _spread(rng, 300, -2.0, 3.0)
    flat[:, 2] = -0.3  # a degenerate box: z constant
    return {
        "negative": _spread(rng, 500, -5.0, -1.0) * [1.0, 2.0, 0.5],
        "straddling": _spread(rng, 400, -1.0, 1.0) * [0.3, 1.0, 2.0],
        "flat": flat,
        "line": np.stack([np.linspace(-1, 1, 50), np.full(50, 2.0), np.full(50, -4.0)], 1),
        "corners": np.array([[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, 1.0, 0.0]]),  # delta wraps
        "one point": np.array([[-0.5, 0.25, 3.0]]),
        "one place": np.full((6, 3), -1.5),
    }


CLOUDS = _clouds()


@pytest.mark.parametrize("name", list(CLOUDS))
def test_decode_inverts_encode_up_to_the_grid(name: str) -> None:
    points = CLOUDS[name]
    box, deltas = encode(points)
    assert box.shape == (2, 3) and box.dtype == np.float64
    np.testing.assert_array_equal(box, [points.min(0), points.max(0)])
    assert deltas.shape == points.shape and deltas.dtype == np.int16
    decoded = decode(box, deltas)
    assert decoded.shape == points.shape and decoded.dtype == np.float32
    assert _gap(decoded, points) <= TOLERANCE * _side(points)


@pytest.mark.parametrize("name", ["negative", "straddling", "flat", "corners"])
def test_encode_reorders_but_keeps_every_point(name: str) -> None:
    """Each point comes back once, each coordinate within half a grid step of its box side."""
    points = CLOUDS[name]
    decoded = decode(*encode(points)).astype(np.float64)
    _, match = cKDTree(decoded).query(points)
    assert sorted(match) == list(range(len(points)))  # a permutation
    side = np.ptp(points, axis=0)
    bound = np.where(side > 0, side, 0.0) / (2 * LEVELS) + 1e-6 * (1 + np.abs(points))
    assert np.all(np.abs(decoded[match] - points) <= bound)


def test_a_constant_axis_comes_back_exactly() -> None:
    decoded = decode(*encode(CLOUDS["flat"]))
    np.testing.assert_array_equal(decoded[:, 2], np.float32(-0.3))
    np.testing.assert_array_equal(decode(*encode(CLOUDS["one place"])), np.float32(-1.5))


def _shape(rng: np.random.Generator, n: int = 50) -> np.ndarray:
    return rng.normal(size=(n, 3)) * rng.uniform(0.2, 2.0, size=3) - rng.uniform(0, 3, size=3)


@pytest.fixture
def tree(tmp_path: Path) -> tuple[Path, dict[str, np.ndarray]]:
    """root/CATEGORY/{train,test}/NAME.{npy,ply}: chair as .npy, table as .ply, sofa not packed.
    Returns the root and the clouds by 'CATEGORY/SPLIT/NAME'."""
    rng = np.random.default_rng(3)
    root, clouds = tmp_path / "modelnet", {}
    for category, suffix in (("chair", ".npy"), ("table", ".ply"), ("sofa", ".npy")):
        for split, count in (("train", 3), ("test", 2)):
            folder = root / category / split
            folder.mkdir(parents=True)
            for i in range(count):
                name, points = f"{category}_{split}_{i:04d}", _shape(rng).astype(np.float32)
                if suffix == ".npy":
                    np.save(folder / f"{name}.npy", points)
                else:
                    write_ply(folder / f"{name}.ply", points)
                if category != "sofa":
                    clouds[f"{category}/{split}/{name}"] = points
    return root, clouds


def test_pack_then_unpack_gives_the_same_tree(tree, tmp_path: Path) -> None:
    root, clouds = tree
    packed = tmp_path / "out" / "sub" / "modelnet.xz"  # its folders are made
    assert pack(root, ["chair", "table"], packed) == {"chair": 5, "table": 5}
    assert packed.is_file()

    unpacked = tmp_path / "unpacked"
    assert unpack(packed, unpacked) == 10
    files = {p.relative_to(unpacked).as_posix() for p in unpacked.rglob("*") if p.is_file()}
    assert files == {f"{name}.npy" for name in clouds}
    for name, points in clouds.items():
        back = np.load(unpacked / f"{name}.npy")
        assert back.shape == points.shape and back.dtype == np.float32
        assert _gap(back, points) <= TOLERANCE * _side(points)

    # the trainers read the unpacked tree like the original: the same splits
    for category in ("chair", "table"):
        before, after = split_files(root, category, 0.3, 0), split_files(unpacked, category, 0.3, 0)
        for split in ("train", "val", "test"):
            assert [p.stem for p in after[split]] == [p.stem for p in before[split]]


def test_pack_of_one_category_holds_only_it(tree, tmp_path: Path) -> None:
    root, clouds = tree
    assert pack(root, ["table"], tmp_path / "table.xz") == {"table": 5}
    assert unpack(tmp_path / "table.xz", tmp_path / "unpacked") == 5
    files = {
        p.relative_to(tmp_path / "unpacked").as_posix()
        for p in (tmp_path / "unpacked").rglob("*.npy")
    }
    assert files == {f"{name}.npy" for name in clouds if name.startswith("table/")}


def test_pack_of_nothing_is_an_error(tree, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no shapes"):
        pack(empty, ["chair"], tmp_path / "a.xz")
    root, _ = tree
    with pytest.raises(ValueError, match="no shapes"):
        pack(root, ["bathtub"], tmp_path / "b.xz")  # a category the tree lacks
    assert not (tmp_path / "a.xz").exists() and not (tmp_path / "b.xz").exists()


def test_a_coarser_grid_is_kept_in_the_pack_and_costs_its_step(tree, tmp_path: Path) -> None:
    """``levels=4095`` packs smaller; ``unpack`` reads the grid from the pack, so the clouds come
    back within that grid's half step (and not within the 16-bit grid's); bad levels refuse."""
    root, clouds = tree
    fine, coarse = tmp_path / "fine.xz", tmp_path / "coarse.xz"
    pack(root, ["chair", "table"], fine)
    pack(root, ["chair", "table"], coarse, levels=4095)
    assert coarse.stat().st_size < fine.stat().st_size
    assert unpack(coarse, tmp_path / "back") == 10
    gaps = []
    for name, points in clouds.items():
        back = np.load(tmp_path / "back" / f"{name}.npy")
        gaps.append(_gap(back, points) / _side(points))
    assert max(gaps) <= np.sqrt(3) / (2 * 4095) + 1e-6
    assert max(gaps) > TOLERANCE / 10  # coarser than the default grid: the level was used
    with pytest.raises(ValueError, match="levels"):
        encode(np.zeros((3, 3)), levels=70000)


def test_a_training_only_pack_keeps_the_layout_and_the_split(tree, tmp_path: Path) -> None:
    """splits=("train",): no test shapes travel, the test folders come back empty, and the
    trainers' train/validation split is the original's."""
    root, _ = tree
    packed = tmp_path / "train.xz"
    assert pack(root, ["chair", "table"], packed, splits=("train",)) == {"chair": 3, "table": 3}
    assert unpack(packed, tmp_path / "unpacked") == 6
    for category in ("chair", "table"):
        assert (tmp_path / "unpacked" / category / "test").is_dir()
        before = split_files(root, category, 0.3, 0)
        after = split_files(tmp_path / "unpacked", category, 0.3, 0)
        assert after["test"] == []
        for split in ("train", "val"):
            assert [p.stem for p in after[split]] == [p.stem for p in before[split]]
    with pytest.raises(ValueError, match="splits"):
        pack(root, ["chair"], tmp_path / "bad.xz", splits=("validation",))


def test_evaluation_of_a_training_only_copy_says_there_is_no_test_split(tree, tmp_path) -> None:
    from itnet.model.categories import category
    from itnet.model.category_set import test_scans
    from itnet.model.scanner import ScanConfig

    root, _ = tree
    pack(root, ["chair"], tmp_path / "train.xz", splits=("train",))
    unpack(tmp_path / "train.xz", tmp_path / "unpacked")
    with pytest.raises(ValueError, match="no test shapes of chair"):
        test_scans(tmp_path / "unpacked", category("chair"), 2, 0, ScanConfig(), tmp_path / "c")
    (tmp_path / "unpacked" / "chair" / "train").rename(tmp_path / "elsewhere")
    (tmp_path / "unpacked" / "chair" / "train").mkdir()
    with pytest.raises(ValueError, match="no training shapes"):
        split_files(tmp_path / "unpacked", "chair", 0.3, 0)
