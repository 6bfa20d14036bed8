import numpy as np
import pycolmap
import pytest

from recon.mvs.colmap_io import read_depth_map, read_map, read_normal_map, write_map


@pytest.fixture
def maps():
    rng = np.random.default_rng(1)
    depth = rng.uniform(1, 5, size=(7, 11)).astype(np.float32)
    depth[2, 3] = 0
    normal = rng.normal(size=(7, 11, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    return depth, normal


def test_round_trip(tmp_path, maps):
    depth, normal = maps
    write_map(tmp_path / "d.bin", depth)
    write_map(tmp_path / "n.bin", normal)
    np.testing.assert_array_equal(read_depth_map(tmp_path / "d.bin"), depth)
    np.testing.assert_array_equal(read_normal_map(tmp_path / "n.bin"), normal)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.bin", "n.bin"]  # no temporary left


def test_depth_maps_are_exchanged_with_pycolmap(tmp_path, maps):
    depth, _ = maps
    write_map(tmp_path / "ours.bin", depth)
    theirs = pycolmap.DepthMap()
    theirs.read(tmp_path / "ours.bin")
    np.testing.assert_array_equal(theirs.to_array(), depth)
    pycolmap.DepthMap.from_array(depth, 1.0, 5.0).write(tmp_path / "theirs.bin")
    np.testing.assert_array_equal(read_depth_map(tmp_path / "theirs.bin"), depth)
    assert (tmp_path / "theirs.bin").read_bytes() == (tmp_path / "ours.bin").read_bytes()


def test_normal_maps_are_stored_plane_by_plane(tmp_path, maps):
    _, normal = maps
    write_map(tmp_path / "n.bin", normal)
    raw = (tmp_path / "n.bin").read_bytes()
    header = b"11&7&3&"
    assert raw.startswith(header)
    planes = np.frombuffer(raw[len(header):], dtype="<f4").reshape(3, 7, 11)
    np.testing.assert_array_equal(planes, normal.transpose(2, 0, 1))
    # pycolmap's binding hands the same bytes back pixel-interleaved (what COLMAP's C++ does not do)
    theirs = pycolmap.NormalMap()
    theirs.read(tmp_path / "n.bin")
    np.testing.assert_array_equal(theirs.to_array(), planes.reshape(7, 11, 3))


def test_wrong_channel_count_is_refused(tmp_path, maps):
    depth, normal = maps
    write_map(tmp_path / "n.bin", normal)
    with pytest.raises(ValueError):
        read_depth_map(tmp_path / "n.bin")
    assert read_map(tmp_path / "n.bin").shape == (7, 11, 3)
