"""Masks all the way (issue 14): a masked pixel never becomes a depth, a fused point, a mesh face or a
texel. Quick checks of each piece here; the whole pipeline on the zoo's masked scene is the slow test."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pycolmap
import pytest
import trimesh

from recon.imaging.masks import mask_at, resample_mask
from recon.mvs.colmap_io import read_depth_map, write_map
from recon.mvs.stereo import map_path, mask_maps
from recon.mvs.views import ViewCamera
from recon.surface.masking import drop_masked_faces, masked_faces


def test_a_mask_follows_its_photo_into_the_undistorted_view():
    distorted = pycolmap.Camera(model="SIMPLE_RADIAL", width=200, height=150, params=[180.0, 100.0, 75.0, -0.2])
    pinhole = pycolmap.Camera(model="PINHOLE", width=160, height=120, params=[150.0, 150.0, 80.0, 60.0])
    u, v = np.meshgrid(np.arange(200) + 0.5, np.arange(150) + 0.5)
    rays = distorted.cam_from_img(np.stack([u.ravel(), v.ravel()], 1)).reshape(150, 200, 2)
    mask = np.hypot(rays[..., 0] - 0.1, rays[..., 1]) < 0.25  # a disc of directions, seen through distortion
    out = resample_mask(mask, distorted, pinhole)
    u, v = np.meshgrid(np.arange(160) + 0.5, np.arange(120) + 0.5)
    rays = pinhole.cam_from_img(np.stack([u.ravel(), v.ravel()], 1)).reshape(120, 160, 2)
    expected = np.hypot(rays[..., 0] - 0.1, rays[..., 1]) < 0.25
    assert np.mean(out != expected) < 0.01  # only pixels on the disc's edge may differ
    assert out.sum() > 1000


def test_masked_pixels_lose_their_depth_and_normal(tmp_path):
    depth = np.full((60, 80), 2.0, np.float32)
    normal = np.zeros((60, 80, 3), np.float32)
    normal[..., 2] = -1
    write_map(map_path(tmp_path, "depth", "a.jpg", "geometric"), depth)
    write_map(map_path(tmp_path, "normal", "a.jpg", "geometric"), normal)
    mask = np.zeros((120, 160), bool)  # the photo's mask, at twice the map's size
    mask[:, :80] = True
    cleared = mask_maps(tmp_path, "a.jpg", mask, "geometric")
    after = read_depth_map(map_path(tmp_path, "depth", "a.jpg", "geometric"))
    assert cleared == 60 * 40
    assert np.all(after[:, :40] == 2.0) and np.all(after[:, 40:] == 0)
    assert mask_maps(tmp_path, "a.jpg", mask, "geometric") == 0  # idempotent
    assert mask_at(mask, 80, 60)[:, :40].all() and not mask_at(mask, 80, 60)[:, 40:].any()


def _looking_down(height: float = 5.0, size: int = 200, focal: float = 200.0) -> ViewCamera:
    """A camera above the origin looking down -z (x right, y down in the image)."""
    R = np.diag([1.0, -1.0, -1.0])
    return ViewCamera("top.jpg", np.array([[focal, 0, size / 2], [0, focal, size / 2], [0, 0, 1]]), R,
                      -R @ np.array([0, 0, height]), size, size)


def test_faces_over_masked_pixels_go_and_the_subject_stays():
    """A 1 x 1 x 1 box (the subject) on a wide ground slab, seen from 5 above; the mask is the box's
    silhouette. The ground around the box goes; the box stays, and so does ground no view sees."""
    ground = trimesh.creation.box(extents=[8, 8, 0.1])
    ground.apply_translation([0, 0, -0.05])
    ground = ground.subdivide_to_size(0.25)
    subject = trimesh.creation.box(extents=[1, 1, 1]).subdivide()
    subject.apply_translation([0, 0, 0.5])
    mesh = trimesh.util.concatenate([ground, subject])
    view = _looking_down()
    half = 200.0 * 0.5 / 4.0  # the box's top (half-width 0.5) at depth 4, focal 200: 25 px
    mask = np.zeros((200, 200), bool)
    mask[round(100 - half):round(100 + half), round(100 - half):round(100 + half)] = True
    kept, dropped = drop_masked_faces(mesh, [view], {view.name: mask})
    assert dropped > 0
    assert not masked_faces(np.asarray(kept.vertices), np.asarray(kept.faces), [view], {view.name: mask}).any()
    centres = kept.triangles_center
    box_top = subject.triangles_center[np.isclose(subject.triangles_center[:, 2], 1.0)]
    assert len(box_top) == np.isclose(centres[:, 2], 1.0).sum()  # the whole top of the box stays
    in_view = np.isclose(centres[:, 2], 0.0) & (np.abs(centres[:, :2]).max(axis=1) < 2.4)
    # ground left in view lies in the box's shadow (from 5 up, the top hides the ground to 0.625)
    assert np.abs(centres[in_view, :2]).max() <= 0.7


def test_a_face_a_pixel_off_the_subjects_outline_stays():
    """The mesh's own error puts faces on the silhouette a pixel to either side of the mask's edge:
    a face one pixel over the background stays, three pixels over it goes."""
    view = _looking_down()  # ground at depth 5: a pixel is 0.025 wide; columns < 100 (x < 0) are the subject
    mask = np.zeros((200, 200), bool)
    mask[:, :100] = True
    pixel = 5.0 / 200.0
    centres = {"inside": -10.5 * pixel, "one_px_over": 0.5 * pixel, "three_px_over": 2.5 * pixel}
    tiny = np.array([[-0.002, -0.002, 0.0], [0.002, -0.002, 0.0], [0.0, 0.002, 0.0]])
    vertices = np.vstack([tiny + [x, 0.0, 0.0] for x in centres.values()])
    faces = np.arange(len(vertices)).reshape(-1, 3)[:, ::-1]  # facing up, towards the camera
    bad = masked_faces(vertices, faces, [view], {view.name: mask})
    assert dict(zip(centres, bad.tolist())) == {"inside": False, "one_px_over": False, "three_px_over": True}


FULL = Path(__file__).resolve().parents[2] / "pipelines" / "full.yaml"
QUICK = ["-o", "undistort.max_image_size=320", "-o", "mvs.max_image_size=320", "-o", "mesh.depth=8",
         "-o", "mesh.target_faces=40000", "-o", "texture.max_faces=20000"]


def _faces_over_masked_truth(scene, workspace) -> tuple[int, object]:
    """Faces of the workspace's mesh (aligned to the ground truth) whose centre a ground-truth view
    sees on a pixel its true mask excludes, 2 px or more from the subject (alignment error aside)."""
    import cv2

    import recon.api
    from recon.eval.groundtruth import load_cameras
    from recon.imaging.masks import load_mask
    from recon.surface.raycast import render_ids, scene_of

    sim = recon.api.model_to_ground_truth(workspace, scene)
    mesh = trimesh.load(workspace / "mesh.ply", process=False)
    vertices, faces = sim.apply(np.asarray(mesh.vertices)), np.asarray(mesh.faces)
    raycast, centres = scene_of(vertices, faces), vertices[faces].mean(axis=1)
    bad = np.zeros(len(faces), bool)
    for name, cam in load_cameras(scene).items():
        mask = load_mask(scene / "masks", name)
        h, w = mask.shape
        depth = render_ids(raycast, cam, w, h)["depth"]
        x = centres @ np.asarray(cam.R).T + np.asarray(cam.t)
        uv = (x @ np.asarray(cam.K).T)[:, :2] / np.maximum(x[:, 2:], 1e-9)
        cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
        idx = np.flatnonzero((x[:, 2] > 0) & (cols >= 0) & (cols < w) & (rows >= 0) & (rows < h))
        idx = idx[x[idx, 2] <= depth[rows[idx], cols[idx]] * 1.001]
        away = cv2.erode(np.uint8(~mask), np.ones((5, 5), np.uint8)).astype(bool)
        bad[idx[away[rows[idx], cols[idx]]]] = True
    return int(bad.sum()), trimesh.Trimesh(vertices, faces, process=False)


@pytest.mark.slow
def test_the_masked_scene_gives_a_mesh_of_the_object_alone(tmp_path):
    """The zoo's masked_object (an object on a cluttered table), full pipeline with and without its
    masks: with them, no face lies over the background in any view, and the mesh is the object's."""
    import subprocess
    import sys

    import recon.api
    from recon.eval.surface import object_metrics

    scene = tmp_path / "scene"
    recon.api.synth(scene, scene="masked_object", width=320, height=240)
    figures = {}
    for label, extra in (("masks", ["-o", f"preprocess.mask_dir={scene / 'masks'}"]), ("none", [])):
        ws = tmp_path / label
        subprocess.run([sys.executable, "-m", "recon.cli", "run", str(FULL), "--images",
                        str(scene / "images"), "--workspace", str(ws), *QUICK, *extra], check=True,
                       capture_output=True)
        over, aligned = _faces_over_masked_truth(scene, ws)
        f = object_metrics(aligned, trimesh.load(scene / "gt" / "object.ply"), thresholds=(0.02,))["fscore@0.02"]
        figures[label] = (over, f)
    assert figures["masks"][0] == 0, figures
    assert figures["none"][0] > 1000  # the check sees the background when it is there
    assert figures["masks"][1] >= figures["none"][1] and figures["masks"][1] > 70, figures
