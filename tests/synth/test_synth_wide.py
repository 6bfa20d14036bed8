"""Fisheye and equirectangular synthetic scenes: files, COLMAP's own projection of the ground truth
lands on the pixels, metadata that recon reads."""

import json

import numpy as np
import pycolmap
import pytest
from PIL import Image

from recon.eval.groundtruth import load_cameras
from recon.sparse.photos import inspect_photo
from recon.synth import load_scene
from recon.synth.wide import (
    fisheye_orbit_views,
    load_views,
    range_points,
    render_fisheye_orbit,
    render_room_walk,
    room_walk_views,
)


@pytest.fixture(scope="module")
def fisheye(tmp_path_factory):
    return render_fisheye_orbit(tmp_path_factory.mktemp("wide") / "fisheye", views=4, width=160, height=120,
                                lens_exif=True)


@pytest.fixture(scope="module")
def panoramas(tmp_path_factory):
    return render_room_walk(tmp_path_factory.mktemp("wide") / "room", views=3, width=192, height=96)


def _reprojection(scene, a: str, b: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface points seen by view a, projected into view b by pycolmap; (pixels, their ranges in b,
    b's range map)."""
    views = load_views(scene.root)
    pts = range_points(np.load(scene.depth_dir / f"{a.split('.')[0]}.npy"), views[a])
    vb = views[b]
    x_cam = pts @ vb.R.T + vb.t
    return vb.colmap().img_from_cam(x_cam), np.linalg.norm(x_cam, axis=1), np.load(scene.depth_dir /
                                                                                    f"{b.split('.')[0]}.npy")


@pytest.mark.parametrize("which", ["fisheye", "panoramas"])
def test_ground_truth_reprojects_through_colmaps_camera(which, request):
    scene = request.getfixturevalue(which)
    names = scene.image_names
    # a view's own surface points land on its pixel centres through pycolmap's img_from_cam
    views = load_views(scene.root)
    depth = np.load(scene.depth_dir / f"{names[0].split('.')[0]}.npy")
    v, u = np.nonzero(depth > 0)
    pts = range_points(depth, views[names[0]])
    px = views[names[0]].colmap().img_from_cam(pts @ views[names[0]].R.T + views[names[0]].t)
    np.testing.assert_allclose(px, np.column_stack([u + 0.5, v + 0.5]), atol=1e-3)
    # and in a neighbouring view, where visible, at the range that view's map holds
    px, rng, depth_b = _reprojection(scene, names[0], names[1])
    ok = np.all(np.isfinite(px), axis=1)
    px, rng = px[ok], rng[ok]
    inside = (px[:, 0] >= 1) & (px[:, 1] >= 1) & (px[:, 0] < depth_b.shape[1] - 1) & (px[:, 1] < depth_b.shape[0] - 1)
    seen = depth_b[px[inside, 1].astype(int), px[inside, 0].astype(int)]
    rel = np.abs(seen - rng[inside]) / rng[inside]
    assert inside.sum() > 500
    assert np.median(rel) < 0.01  # same surface (occluded points and pixel rounding make the rest)


def test_files_and_scene_metadata(fisheye, panoramas):
    for scene, model in ((fisheye, "OPENCV_FISHEYE"), (panoramas, "EQUIRECTANGULAR")):
        meta = json.loads(scene.scene_json.read_text())
        assert meta["camera_model"] == model and meta["depth"] == "range"
        assert load_scene(scene.root) == scene
        assert set(load_cameras(scene.root)) == set(scene.image_names)  # recon eval reads the poses
        assert sorted(p.name for p in scene.images_dir.iterdir()) == sorted(scene.image_names)
        assert scene.extent > 1.0
    f = fisheye_orbit_views(4, 160, 120)["view_000.jpg"].params
    assert f[0] == pytest.approx(np.hypot(160, 120) / 2 / np.radians(88.0))  # 176 degrees across the diagonal
    pano = Image.open(panoramas.images_dir / panoramas.image_names[0])
    assert pano.size == (192, 96)
    # the sky is never seen inside the room: every panorama pixel hits a wall, the floor or an object
    assert (np.load(panoramas.depth_dir / "pano_000.npy") > 0).all()


def test_metadata_says_fisheye_and_360(fisheye, panoramas):
    name = fisheye.image_names[0]
    assert inspect_photo(fisheye.images_dir / name, name).projection == "fisheye"
    name = panoramas.image_names[0]
    assert inspect_photo(panoramas.images_dir / name, name).projection == "equirectangular"


def test_panoramas_walk_upright_through_the_room():
    views = room_walk_views(16, 256, 128)
    centres = np.array([-v.R.T @ v.t for v in views.values()])
    steps = np.linalg.norm(np.diff(centres[:, :2], axis=0), axis=1)
    assert 0.25 < steps.min() and steps.max() < 0.45  # ~4.7 m in 15 steps
    for v in views.values():
        up_in_camera = v.R @ [0.0, 0.0, 1.0]
        assert np.degrees(np.arccos(-up_in_camera[1])) < 6  # camera -y is world up within a few degrees
    with pytest.raises(ValueError, match="twice as wide"):
        room_walk_views(2, 256, 256)
    assert pycolmap.Camera(model="EQUIRECTANGULAR", width=256, height=128,
                           params=list(views["pano_000.jpg"].params)).params.tolist() == [256, 128]


@pytest.mark.parametrize("which", ["fisheye", "panoramas"])
def test_surface_evaluation_reads_the_range_maps(which, request):
    from recon.eval.surface import observed_points, surface_metrics

    scene = request.getfixturevalue(which)
    seen = observed_points(scene, 0.002 * scene.extent / 2)
    figures = surface_metrics(seen, scene)  # the observable surface itself: on the true mesh, complete
    assert figures["accuracy@0.002"] > 99.9 and figures["completeness@0.002"] > 99.9


def test_recon_synth_renders_them(tmp_path):
    from recon import api
    from recon.config import ConfigError

    out = api.synth(tmp_path / "pano", camera="360", views=2, width=128, height=64, seed=0, holdout=None)
    assert json.loads((out / "gt" / "scene.json").read_text())["camera_model"] == "EQUIRECTANGULAR"
    assert load_scene(out).name == "room_walk" and load_scene(out).views == 2
    with pytest.raises(ConfigError, match="twice as wide"):
        api.synth(tmp_path / "bad", camera="360", width=128, height=128)
    with pytest.raises(ConfigError, match="--scene"):
        api.synth(tmp_path / "bad", camera="fisheye", scene="anything")
