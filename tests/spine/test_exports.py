"""Exports open in the tools people use: pycolmap (COLMAP), trimesh (PLY), nerfstudio (transforms.json)."""

from __future__ import annotations

import json

import numpy as np
import pycolmap
import trimesh

from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.sparse.database import opened, private_copy


def test_workspace_contract(sparse_workspace):
    for rel in ("database.db", "sparse/0/cameras.bin", "sparse/0/images.bin", "sparse/0/points3D.bin",
                "sparse_text/cameras.txt", "points.ply", "transforms.json", "images"):
        assert (sparse_workspace / rel).exists(), rel
    # pycolmap writes to a database it opens: read the session's cached one through a copy
    with private_copy(sparse_workspace / "database.db") as copy, opened(copy) as db:
        assert db.num_images() == 16 and db.num_verified_image_pairs() > 0


def test_model_loads_and_matches_ground_truth(sparse_workspace, small_scene):
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    text = pycolmap.Reconstruction(str(sparse_workspace / "sparse_text"))
    assert rec.num_reg_images() == text.num_reg_images() == 16
    assert rec.num_points3D() == text.num_points3D() > 500
    est = {img.name: (img.cam_from_world().rotation.matrix(), img.cam_from_world().translation)
           for img in rec.images.values() if img.has_pose}
    figures = pose_metrics(est, load_cameras(small_scene))
    assert figures["registered"] == 16 and figures["auc@5"] > 90


def test_points_ply_has_model_points_and_colours(sparse_workspace):
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    cloud = trimesh.load(sparse_workspace / "points.ply")
    assert isinstance(cloud, trimesh.PointCloud)
    assert len(cloud.vertices) == rec.num_points3D()
    xyz = np.array(sorted(tuple(p.xyz) for p in rec.points3D.values()))
    assert np.allclose(np.array(sorted(map(tuple, cloud.vertices))), xyz, atol=1e-5)
    assert cloud.colors[:, :3].std() > 5  # real colours, not a constant


def test_transforms_json_in_nerfstudio_convention(sparse_workspace):
    data = json.loads((sparse_workspace / "transforms.json").read_text())
    for key in ("camera_model", "fl_x", "fl_y", "cx", "cy", "w", "h", "k1", "k2", "p1", "p2", "frames"):
        assert key in data, key
    assert data["camera_model"] == "OPENCV" and data["w"] == 320 and data["h"] == 240
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    assert len(data["frames"]) == rec.num_reg_images()
    cam = next(iter(rec.cameras.values()))
    assert np.isclose(data["fl_x"], cam.params[0]) and np.isclose(data["k1"], cam.params[3])
    for frame in data["frames"]:
        assert (sparse_workspace / frame["file_path"]).exists()
        c2w = np.array(frame["transform_matrix"])
        assert c2w.shape == (4, 4) and np.allclose(c2w[3], [0, 0, 0, 1])
        img = rec.find_image_with_name(frame["file_path"].removeprefix("images/"))
        # nerfstudio: OpenGL camera axes; the camera looks down its -z axis
        assert np.allclose(c2w[:3, 3], img.projection_center(), atol=1e-6)
        assert np.allclose(-c2w[:3, 2], img.viewing_direction(), atol=1e-6)
        assert np.allclose(np.linalg.det(c2w[:3, :3]), 1.0, atol=1e-6)


def test_transforms_json_names_the_sparse_points_as_nerfstudio_reads_them(sparse_workspace):
    """nerfstudio's dataparser opens ``ply_file_path`` (relative to transforms.json) with open3d and
    starts splatfacto from its points and colours."""
    from recon._open3d import open3d

    transforms = sparse_workspace / "transforms.json"
    data = json.loads(transforms.read_text())
    cloud = open3d().io.read_point_cloud(str(transforms.parent / data["ply_file_path"]))
    rec = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    xyz = np.array(sorted(tuple(p.xyz) for p in rec.points3D.values()))
    assert np.allclose(np.array(sorted(map(tuple, np.asarray(cloud.points)))), xyz, atol=1e-5)
    rgb = np.array(sorted(tuple(p.color) for p in rec.points3D.values()))
    assert np.array_equal(np.array(sorted(map(tuple, np.round(np.asarray(cloud.colors) * 255).astype(int)))), rgb)
