"""The synthetic scene: files, ground-truth consistency, texture richness, determinism, EXIF."""

import json

import numpy as np
import pytest
from PIL import ExifTags, Image

from recon.geometry.transforms import backproject, project
from recon.synth import load_scene, render_scene, scene_cameras
from recon.synth.render import Renderer
from recon.synth.scene import TARGET, build_scene


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    return render_scene(tmp_path_factory.mktemp("synth") / "scene", views=12, width=320, height=240, seed=0,
                        holdout=2)


def test_layout_and_round_trip(scene):
    assert len(list(scene.images_dir.glob("view_*.jpg"))) == 12
    assert sorted(p.name for p in scene.holdout_images_dir.iterdir()) == ["holdout_000.jpg", "holdout_001.jpg"]
    frames = json.loads(scene.cameras_path.read_text())["frames"]
    assert [f["name"] for f in frames] == [f"view_{i:03d}.jpg" for i in range(12)]
    assert set(frames[0]) == {"name", "width", "height", "K", "R", "t"}
    assert len(json.loads(scene.holdout_cameras_path.read_text())["frames"]) == 2
    for name in (*scene.image_names, *scene.holdout_names):
        assert scene.depth(name).shape == (240, 320) and scene.depth(name).dtype == np.float32
        assert scene.normal(name).shape == (240, 320, 3) and scene.normal(name).dtype == np.float32
    assert load_scene(scene.root) == scene
    assert load_scene(scene.scene_json) == scene
    import trimesh

    mesh = trimesh.load(scene.mesh_path, process=False)
    np.testing.assert_allclose(mesh.bounds, [scene.bbox_min, scene.bbox_max], atol=1e-6)
    # the extent covers the objects and the seen ground, not more than the whole bounding box
    assert 3.0 < scene.extent <= np.linalg.norm(np.subtract(scene.bbox_max, scene.bbox_min)) + 1e-6


def test_cameras_match_scene_cameras(scene):
    regular, held = scene_cameras(12, 320, 240, seed=0, holdout=2)
    for name, cam in scene.cameras().items():
        np.testing.assert_allclose(cam.R, regular[name].R)
        np.testing.assert_allclose(cam.t, regular[name].t)
        np.testing.assert_allclose(cam.K, [[288, 0, 160], [0, 288, 120], [0, 0, 1]])
    for name, cam in scene.cameras(holdout=True).items():
        np.testing.assert_allclose(cam.t, held[name].t)


def _sample_inverse_depth(depth, uv):
    """Bilinear interpolation of 1/depth (exact on planes) at pixel positions uv (COLMAP convention);
    NaN where a corner is empty or the corners disagree (an occlusion edge)."""
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    h, w = depth.shape
    ok = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    x0, y0, fx, fy = x0[ok], y0[ok], (x - np.floor(x))[ok], (y - np.floor(y))[ok]
    corners = np.stack([depth[y0, x0], depth[y0, x0 + 1], depth[y0 + 1, x0], depth[y0 + 1, x0 + 1]])
    smooth = (corners.min(0) > 0) & (corners.max(0) < 1.02 * corners.min(0))
    inv = 1.0 / np.where(corners > 0, corners, 1.0)
    val = (inv[0] * (1 - fx) + inv[1] * fx) * (1 - fy) + (inv[2] * (1 - fx) + inv[3] * fx) * fy
    out = np.full(len(uv), np.nan)
    out[np.flatnonzero(ok)[smooth]] = 1.0 / val[smooth]
    return out


@pytest.mark.parametrize("pair", [("view_000.jpg", "view_001.jpg"), ("view_005.jpg", "view_007.jpg"),
                                  ("view_006.jpg", "holdout_001.jpg")])
def test_depth_reprojects_between_views(scene, pair):
    cams = {**scene.cameras(), **scene.cameras(holdout=True)}
    a, b = (cams[n] for n in pair)
    da, db = scene.depth(pair[0]), scene.depth(pair[1])
    v, u = np.nonzero(da > 0)
    X = backproject(a.K, a.R, a.t, np.column_stack([u + 0.5, v + 0.5]), da[v, u])
    uv, z = project(b.K, b.R, b.t, X)
    seen = _sample_inverse_depth(db, uv)
    visible = np.isfinite(seen) & (seen > z * (1 - 1e-2))  # not occluded in b
    assert visible.mean() > 0.5
    rel = np.abs(seen[visible] - z[visible]) / z[visible]
    assert np.median(rel) < 1e-5  # a 0.25 px convention slip gives 2e-4
    assert np.mean(rel < 1e-3) > 0.99


def test_normals_unit_facing_and_consistent_with_depth(scene):
    for name, cam in scene.cameras().items():
        depth, normal = scene.depth(name), scene.normal(name)
        valid = depth > 0
        np.testing.assert_allclose(np.linalg.norm(normal[valid], axis=1), 1.0, atol=1e-5)
        assert not normal[~valid].any()
        v, u = np.nonzero(valid)
        rays = np.column_stack([u + 0.5, v + 0.5, np.ones(len(u))]) @ np.linalg.inv(cam.K).T
        assert (np.einsum("ij,ij->i", rays, normal[valid]) < 0).all()
    # normals agree with the surface the depth map describes (cross product of neighbour offsets)
    cam = scene.cameras()["view_000.jpg"]
    depth, normal = scene.depth("view_000.jpg"), scene.normal("view_000.jpg")
    h, w = depth.shape
    vv, uu = np.mgrid[0:h, 0:w]
    pts = backproject(cam.K, np.eye(3), np.zeros(3), np.column_stack([uu.ravel() + 0.5, vv.ravel() + 0.5]),
                      depth.ravel()).reshape(h, w, 3)
    du, dv = pts[1:-1, 2:] - pts[1:-1, :-2], pts[2:, 1:-1] - pts[:-2, 1:-1]
    est = np.cross(du, dv)
    d = depth
    smooth = (d[1:-1, 1:-1] > 0) & (np.abs(d[1:-1, 2:] - d[1:-1, :-2]) < 0.01 * d[1:-1, 1:-1]) & \
             (np.abs(d[2:, 1:-1] - d[:-2, 1:-1]) < 0.01 * d[1:-1, 1:-1]) & (np.minimum(d[2:, 1:-1], d[:-2, 1:-1]) > 0)
    est = est[smooth] / np.linalg.norm(est[smooth], axis=1, keepdims=True)
    cos = np.einsum("ij,ij->i", est, normal[1:-1, 1:-1][smooth])
    assert np.median(np.degrees(np.arccos(np.clip(np.abs(cos), -1, 1)))) < 1.0
    assert np.median(cos) < 0  # cross(du, dv) points away from the camera; GT normals face it


def test_images_are_textured(scene):
    import cv2

    for name in scene.image_names[:4]:
        gray = np.asarray(Image.open(scene.images_dir / name).convert("L"), dtype=np.float32)
        depth = scene.depth(name)
        surface = cv2.erode((depth > 0).astype(np.uint8), np.ones((5, 5))) > 0
        lap = cv2.Laplacian(gray, cv2.CV_32F)
        assert lap[surface].var() > 300.0  # measured ~1000 at 320x240, ~760 at 640x480
        # few flat blocks: std over 8x8 blocks of surface pixels
        h, w = gray.shape
        blocks = gray[: h // 8 * 8, : w // 8 * 8].reshape(h // 8, 8, w // 8, 8)
        full = surface[: h // 8 * 8, : w // 8 * 8].reshape(h // 8, 8, w // 8, 8).all(axis=(1, 3))
        assert np.mean(blocks.std(axis=(1, 3))[full] < 3.0) < 0.05
        # sky is one uniform colour and has no depth
        sky = cv2.erode((depth == 0).astype(np.uint8), np.ones((5, 5))) > 0
        assert sky.any() and gray[sky].std() < 2.0


def test_views_are_photo_consistent(scene):
    # warp view 1 into view 0 through the ground-truth depth: view-independent shading means the
    # colours agree up to resampling and JPEG (measured: median |diff| ~2 grey levels, NCC ~0.97)
    import cv2

    cams = scene.cameras()
    a, b = cams["view_000.jpg"], cams["view_001.jpg"]
    i0, i1 = (np.asarray(Image.open(scene.images_dir / n).convert("L"), np.float32)
              for n in ("view_000.jpg", "view_001.jpg"))
    d0, d1 = scene.depth("view_000.jpg"), scene.depth("view_001.jpg")
    h, w = d0.shape
    vv, uu = np.mgrid[0:h, 0:w]
    X = backproject(a.K, a.R, a.t, np.column_stack([uu.ravel() + 0.5, vv.ravel() + 0.5]), d0.ravel())
    uv, z = project(b.K, b.R, b.t, X)
    mx, my = ((uv[:, k] - 0.5).reshape(h, w).astype(np.float32) for k in (0, 1))
    warped = cv2.remap(i1, mx, my, cv2.INTER_LINEAR, borderValue=-1)
    seen = cv2.remap(d1, mx, my, cv2.INTER_NEAREST, borderValue=0)
    ok = (d0 > 0) & (warped >= 0) & (np.abs(seen - z.reshape(h, w)) < 0.01 * z.reshape(h, w))
    ok = cv2.erode(ok.astype(np.uint8), np.ones((5, 5))) > 0
    assert ok.mean() > 0.4
    assert np.median(np.abs(warped - i0)[ok]) < 4.0
    k = (7, 7)
    m0, m1 = cv2.blur(i0, k), cv2.blur(warped, k)
    cov = cv2.blur(i0 * warped, k) - m0 * m1
    var = (cv2.blur(i0 * i0, k) - m0**2) * (cv2.blur(warped * warped, k) - m1**2)
    ncc = (cov / np.sqrt(np.maximum(var, 1e-6)))[ok]
    assert np.median(ncc) > 0.9


def test_render_is_deterministic_and_seeded(tmp_path):
    a = render_scene(tmp_path / "a", views=3, width=160, height=120, seed=5)
    b = render_scene(tmp_path / "b", views=3, width=160, height=120, seed=5)
    c = render_scene(tmp_path / "c", views=3, width=160, height=120, seed=6)
    for name in a.image_names:
        assert (a.images_dir / name).read_bytes() == (b.images_dir / name).read_bytes()
        assert np.array_equal(a.depth(name), b.depth(name))
        assert not np.array_equal(a.depth(name), c.depth(name))
    assert a.mesh_path.read_bytes() == b.mesh_path.read_bytes() != c.mesh_path.read_bytes()
    assert a.extent == b.extent
    # rendering again with fewer views into the same folder leaves no stale files
    d = render_scene(tmp_path / "a", views=2, width=160, height=120, seed=5)
    assert sorted(p.name for p in d.images_dir.iterdir()) == ["view_000.jpg", "view_001.jpg"]
    assert len(list(d.depth_dir.iterdir())) == 2


def test_exif_focal_matches_K(scene):
    import pycolmap

    cam = scene.cameras()["view_000.jpg"]
    with Image.open(scene.images_dir / "view_000.jpg") as im:
        exif = im.getexif()
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    assert exif[ExifTags.Base.Make] == "recon" and exif[ExifTags.Base.Model] == "synthetic"
    res_px_per_mm = float(sub[ExifTags.Base.FocalPlaneXResolution]) / 10.0
    assert sub[ExifTags.Base.FocalPlaneResolutionUnit] == 3
    assert float(sub[ExifTags.Base.FocalLength]) * res_px_per_mm == pytest.approx(cam.K[0, 0], rel=1e-4)
    assert float(sub[ExifTags.Base.FocalLength]) == pytest.approx(cam.K[0, 0] / cam.width * 36.0, rel=1e-4)
    f35 = sub[ExifTags.Base.FocalLengthIn35mmFilm]
    assert f35 == round(cam.K[0, 0] * 43.27 / np.hypot(cam.width, cam.height))
    prior = pycolmap.infer_camera_from_image(scene.images_dir / "view_000.jpg")
    assert prior.has_prior_focal_length
    assert prior.mean_focal_length() == pytest.approx(cam.K[0, 0], rel=0.02)


def test_png_format_is_lossless_without_exif(tmp_path):
    s = render_scene(tmp_path / "png", views=2, width=96, height=72, image_format="png")
    assert s.image_names == ("view_000.png", "view_001.png")
    with Image.open(s.images_dir / "view_000.png") as im:
        assert im.format == "PNG" and len(im.getexif()) == 0
    assert load_scene(s.root).image_format == "png"


def test_sift_finds_many_features_on_neighbouring_views():
    import pycolmap

    regular, _ = scene_cameras(24, 640, 480, seed=0)
    renderer = Renderer(build_scene(0))
    options = pycolmap.FeatureExtractionOptions()
    extractor = pycolmap.FeatureExtractor.create(options, pycolmap.Device.cpu)
    for name in ("view_000.jpg", "view_001.jpg"):
        rgb, _, _ = renderer.render(regular[name])
        gray = np.ascontiguousarray(np.asarray(Image.fromarray(rgb).convert("L")))
        keypoints = extractor.extract_from_uint8_array(gray)[0]
        assert len(keypoints) > 1500


def test_scene_cameras_paths():
    regular, held = scene_cameras(8, 320, 240, seed=1, holdout=3)
    assert list(held) == ["holdout_000.jpg", "holdout_001.jpg", "holdout_002.jpg"]
    for cam in (*regular.values(), *held.values()):
        uv, z = cam.project(TARGET[None])
        np.testing.assert_allclose(uv[0], [160, 120], atol=1e-6)  # orbit views look at the scene centre
        elevation = np.degrees(np.arcsin((cam.center[2] - TARGET[2]) / np.linalg.norm(cam.center - TARGET)))
        assert 25 < elevation < 35
    # hold-out views sit between regular ones, and adding them does not move the regular ones
    az = {n: np.degrees(np.arctan2(c.center[1], c.center[0])) % 360 for n, c in {**regular, **held}.items()}
    assert 20 < az["holdout_000.jpg"] < 25
    same, _ = scene_cameras(8, 320, 240, seed=1)
    for name in regular:
        np.testing.assert_array_equal(regular[name].t, same[name].t)
    line, _ = scene_cameras(6, 320, 240, seed=0, path="line")
    centres = np.array([c.center for c in line.values()])
    steps = np.diff(centres, axis=0)
    assert np.all(steps[:, 0] > 0.5)  # moving sideways
    assert all(np.allclose(c.R, line["view_000.jpg"].R) for c in line.values())
    with pytest.raises(ValueError):
        scene_cameras(4, path="spiral")
