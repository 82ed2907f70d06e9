import numpy as np
import pytest

from itnet.cloud_io import CloudReadError, read_cloud, write_ply


def test_binary_ply_round_trip(tmp_path, rng):
    pts = rng.normal(size=(123, 3)).astype(np.float32)
    write_ply(tmp_path / "a.ply", pts)
    assert np.allclose(read_cloud(tmp_path / "a.ply"), pts)


def test_ascii_ply_with_extra_properties_and_faces(tmp_path):
    text = (
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        "property float z\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_indices\n"
        "end_header\n0 0 0 255\n1 0 0 0\n0 1 2 9\n3 0 1 2\n"
    )
    (tmp_path / "m.ply").write_text(text)
    assert np.allclose(read_cloud(tmp_path / "m.ply"), [[0, 0, 0], [1, 0, 0], [0, 1, 2]])


def test_big_endian_ply(tmp_path, rng):
    pts = rng.normal(size=(10, 3))
    header = (
        "ply\nformat binary_big_endian 1.0\nelement vertex 10\nproperty double x\n"
        "property double y\nproperty double z\nend_header\n"
    )
    (tmp_path / "b.ply").write_bytes(header.encode() + pts.astype(">f8").tobytes())
    assert np.allclose(read_cloud(tmp_path / "b.ply"), pts)


def test_pcd_ascii_binary_and_shipped_dataset(tmp_path, rng):
    pts = rng.normal(size=(20, 3)).astype(np.float32)
    head = "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 20\nHEIGHT 1\nPOINTS 20\n"
    table = np.concatenate([pts, np.zeros((20, 1), np.float32)], 1)
    (tmp_path / "a.pcd").write_text(
        head + "DATA ascii\n" + "\n".join(" ".join(map(str, r)) for r in table)
    )
    (tmp_path / "b.pcd").write_bytes(
        (head + "DATA binary\n").encode() + table.astype("<f4").tobytes()
    )
    assert np.allclose(read_cloud(tmp_path / "a.pcd"), pts, atol=1e-6)
    assert np.allclose(read_cloud(tmp_path / "b.pcd"), pts)


def test_text_and_npy(tmp_path, rng):
    pts = rng.normal(size=(7, 3))
    np.savetxt(tmp_path / "a.xyz", np.concatenate([pts, np.ones((7, 3))], 1))
    (tmp_path / "b.pts").write_text("7\n" + "\n".join(",".join(map(str, p)) for p in pts))
    np.save(tmp_path / "c.npy", pts)
    for name in ("a.xyz", "b.pts", "c.npy"):
        assert np.allclose(read_cloud(tmp_path / name), pts)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("missing.ply", None, "no such file"),
        ("a.obj", b"v 0 0 0", "unknown format"),
        (
            "t.ply",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
            b"property float y\nproperty float z\nend_header\n" + b"\0" * 40,
            "truncated",
        ),
        ("h.ply", b"ply\n" + b"comment x\n" * 10000, "end_header"),
        ("n.ply", b"not a ply", "magic"),
        ("e.xyz", b"", "no points"),
        ("bad.xyz", b"1 2 3\n4 5\n", "fewer than 3"),
        ("w.npy", None, "shape"),
        (
            "c.pcd",
            b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 5\nDATA binary\n\0\0",
            "truncated",
        ),
        ("g.pcd", b"\xff\xfe garbage", "DATA"),
    ],
)
def test_bad_files_raise_clear_errors(tmp_path, name, content, message):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    elif name.endswith(".npy"):
        np.save(path, np.zeros((4, 2)))
    with pytest.raises(CloudReadError, match=message) as info:
        read_cloud(path)
    assert name in str(info.value)
