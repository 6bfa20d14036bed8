"""Ground-truth camera readers: each format's convention, and the real datasets' epipolar geometry."""

import json
import os
from pathlib import Path

import numpy as np
import pytest

from recon.eval.groundtruth import Camera, load_cameras, write_cameras
from recon.geometry.transforms import camera_center


def datasets_root() -> Path:
    return Path(os.environ.get("RECON_DATASETS", Path(__file__).resolve().parents[2].parent / "shared" / "datasets"))


def look_at_c2w(center, target):
    """Camera-to-world rotation (columns = camera x right, y down, z forward) looking at target, z up."""
    f = np.asarray(target, float) - center
    f /= np.linalg.norm(f)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    return np.column_stack([r, np.cross(f, r), f])


K = np.array([[500.0, 0, 320], [0, 510.0, 240], [0, 0, 1]])
C = np.array([2.0, -3.0, 1.5])
TARGET = np.array([0.1, 0.2, 0.3])
R_C2W = look_at_c2w(C, TARGET)


def check_camera(cam: Camera):
    """The camera sits at C, looks at TARGET (principal point), and world +z is up in its image."""
    np.testing.assert_allclose(cam.center, C, atol=1e-9)
    uv, z = cam.project(np.array([TARGET, TARGET + [0, 0, 0.1]]))
    np.testing.assert_allclose(uv[0], [K[0, 2], K[1, 2]], atol=1e-9)
    assert z[0] == pytest.approx(np.linalg.norm(TARGET - C))
    assert uv[1, 1] < uv[0, 1]  # up in the world is up (smaller v) in the image
    np.testing.assert_allclose(cam.K, K)


def test_middlebury_par(tmp_path):
    R = R_C2W.T
    t = -R @ C
    (tmp_path / "gt").mkdir()
    (tmp_path / "images").mkdir()
    from PIL import Image

    Image.new("RGB", (64, 48)).save(tmp_path / "images" / "a.png")
    line = " ".join(f"{v:.17g}" for v in (*K.ravel(), *R.ravel(), *t))
    (tmp_path / "gt" / "objR_par.txt").write_text(f"2\na.png {line}\nb.png {line}\n")
    cams = load_cameras(tmp_path)
    assert list(cams) == ["a.png", "b.png"]
    check_camera(cams["a.png"])
    assert (cams["a.png"].width, cams["a.png"].height) == (64, 48)
    assert (cams["b.png"].width, cams["b.png"].height) == (0, 0)  # no image: size unknown
    np.testing.assert_allclose(cams["a.png"].P, K @ np.column_stack([R, t]))


def test_strecha_camera_files(tmp_path):
    folder = tmp_path / "gt" / "cams"
    folder.mkdir(parents=True)
    def fmt(v):
        return " ".join(f"{x:.17g}" for x in v)

    rows = [*(fmt(r) for r in K), "0 0 0", *(fmt(r) for r in R_C2W), fmt(C), "640 480"]
    (folder / "0000.jpg.camera").write_text("\n".join(rows) + "\n")
    cams = load_cameras(tmp_path)
    assert list(cams) == ["0000.jpg"]
    check_camera(cams["0000.jpg"])
    assert (cams["0000.jpg"].width, cams["0000.jpg"].height) == (640, 480)
    assert list(load_cameras(folder / "0000.jpg.camera")) == ["0000.jpg"]


@pytest.mark.parametrize("per_frame", [False, True])
def test_nerfstudio_transforms(tmp_path, per_frame):
    c2w = np.eye(4)
    c2w[:3, :3] = R_C2W * [1, -1, -1]  # OpenGL camera axes: y up, z backwards
    c2w[:3, 3] = C
    intr = {"fl_x": 500.0, "fl_y": 510.0, "cx": 320.0, "cy": 240.0, "w": 640, "h": 480}
    frame = {"file_path": "images/frame_00001.png", "transform_matrix": c2w.tolist()}
    data = {"frames": [{**frame, **intr}]} if per_frame else {**intr, "frames": [frame]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    cams = load_cameras(tmp_path)
    check_camera(cams["frame_00001.png"])
    assert (cams["frame_00001.png"].width, cams["frame_00001.png"].height) == (640, 480)


def test_instant_ngp_camera_angle(tmp_path):
    c2w = np.eye(4)
    c2w[:3, :3] = R_C2W * [1, -1, -1]
    c2w[:3, 3] = C
    data = {"camera_angle_x": 2 * np.arctan(320 / 500.0), "w": 640, "h": 480,
            "frames": [{"file_path": "./train/r_0", "transform_matrix": c2w.tolist()}]}
    (tmp_path / "transforms.json").write_text(json.dumps(data))
    cam = load_cameras(tmp_path / "transforms.json")["r_0"]
    np.testing.assert_allclose(cam.K, [[500, 0, 320], [0, 500, 240], [0, 0, 1]])
    np.testing.assert_allclose(cam.center, C)


def test_recon_cameras_json_round_trip(tmp_path):
    R = R_C2W.T
    cams = {"view_000.jpg": Camera(K, R, -R @ C, 640, 480)}
    (tmp_path / "gt").mkdir()
    write_cameras(tmp_path / "gt" / "cameras.json", cams)
    back = load_cameras(tmp_path)
    check_camera(back["view_000.jpg"])
    assert back["view_000.jpg"].radial == (0.0, 0.0)
    write_cameras(tmp_path / "gt" / "cameras.json", {"view_000.jpg": Camera(K, R, -R @ C, 640, 480, (-0.08, 0.01))})
    assert load_cameras(tmp_path)["view_000.jpg"].radial == (-0.08, 0.01)


def test_a_lens_with_distortion_projects_as_opencv_does_and_back():
    import cv2

    R = R_C2W.T
    cam = Camera(K, R, -R @ C, 640, 480, (-0.08, 0.01))
    pixels = np.array([[0.5, 0.5], [639.5, 479.5], [320.0, 240.0], [100.0, 400.0], [600.0, 30.0]])
    depth = np.array([2.0, 3.0, 4.0, 5.0, 6.0])
    world = cam.backproject(pixels, depth)
    uv, z = cam.project(world)
    np.testing.assert_allclose(uv, pixels, atol=1e-6)
    np.testing.assert_allclose(z, depth)
    opencv, _ = cv2.projectPoints(world, cv2.Rodrigues(cam.R)[0], cam.t, K, np.array([-0.08, 0.01, 0.0, 0.0]))
    np.testing.assert_allclose(opencv[:, 0], pixels, atol=1e-6)
    # the corner's ray meets a pinhole's image farther out: barrel distortion draws it in
    straight = K @ cam.rays(pixels[:1])[0]
    assert np.hypot(*(straight[:2] - K[:2, 2])) > np.hypot(*(pixels[0] - K[:2, 2])) + 10


def test_unknown_folder_raises(tmp_path):
    with pytest.raises(ValueError):
        load_cameras(tmp_path)
    with pytest.raises(FileNotFoundError):
        load_cameras(tmp_path / "missing")


def _sampson(F, x1, x2):
    X1 = np.column_stack([x1, np.ones(len(x1))])
    X2 = np.column_stack([x2, np.ones(len(x2))])
    Fx1, Ftx2 = X1 @ F.T, X2 @ F
    num = np.einsum("ij,ij->i", X2, Fx1) ** 2
    return np.sqrt(num / (Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2))


def _fundamental(a: Camera, b: Camera):
    R = b.R @ a.R.T
    t = b.t - R @ a.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    return np.linalg.inv(b.K).T @ tx @ R @ np.linalg.inv(a.K)


@pytest.mark.datasets
@pytest.mark.parametrize("name,count,size,pair,scale,max_median", [
    ("temple_ring", 47, (640, 480), (0, 1), 1.0, 0.3),
    ("fountain_p11", 11, (3072, 2048), (5, 6), 0.25, 0.5),
    ("dino_sparse_ring", 16, (640, 480), (0, 1), 1.0, 1.0),
])
def test_real_dataset_cameras_fit_sift_matches(name, count, size, pair, scale, max_median):
    import cv2

    root = datasets_root() / name
    if not root.is_dir():
        pytest.skip(f"{root} absent")
    cams = load_cameras(root)
    assert len(cams) == count
    assert all((c.width, c.height) == size for c in cams.values())
    assert all(np.allclose(c.R @ c.R.T, np.eye(3), atol=1e-5) for c in cams.values())
    names = sorted(cams)
    n1, n2 = names[pair[0]], names[pair[1]]
    imgs = [cv2.imread(str(root / "images" / n), cv2.IMREAD_GRAYSCALE) for n in (n1, n2)]
    if scale != 1.0:
        imgs = [cv2.resize(im, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) for im in imgs]
    sift = cv2.SIFT_create()
    (k1, d1), (k2, d2) = (sift.detectAndCompute(im, None) for im in imgs)
    good = [m for m, n in cv2.BFMatcher().knnMatch(d1, d2, k=2) if m.distance < 0.75 * n.distance]
    assert len(good) >= 30
    # OpenCV puts pixel centres at integers, COLMAP at half-integers
    x1 = (np.array([k1[m.queryIdx].pt for m in good]) + 0.5) / scale
    x2 = (np.array([k2[m.trainIdx].pt for m in good]) + 0.5) / scale
    err = _sampson(_fundamental(cams[n1], cams[n2]), x1, x2)
    assert np.median(err) < max_median
    # a wrong convention (camera-to-world taken as world-to-camera) breaks the constraint
    wrong = {n: Camera(c.K, c.R.T, camera_center(c.R, c.t), c.width, c.height) for n, c in cams.items()}
    assert np.median(_sampson(_fundamental(wrong[n1], wrong[n2]), x1, x2)) > 5 * max_median
