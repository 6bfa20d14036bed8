"""Reprojection of a fused cloud into ground-truth cameras (recon.eval.reprojection)."""

import numpy as np

from recon.eval.groundtruth import Camera
from recon.eval.reprojection import DenseView, refine_alignment, reprojection_errors
from recon.geometry.transforms import Similarity, apply_matrix

W, H = 320, 240
K = np.array([[300.0, 0, W / 2], [0, 300.0, H / 2], [0, 0, 1]])


def _rotation_y(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _scene():
    """Three cameras 5 units in front of the plane z = 0, looking along +z; a grid of points on the plane."""
    cams = {}
    for i, x in enumerate((-0.5, 0.0, 0.5)):
        R = _rotation_y(-6 * x)
        centre = np.array([x, 0.0, -5.0])
        cams[f"v{i}.jpg"] = Camera(K, R, -R @ centre, W, H)
    g = np.linspace(-1, 1, 41)
    xs, ys = np.meshgrid(g, g)
    points = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)])
    return cams, points


def _depth(cam: Camera) -> np.ndarray:
    """The depth map of the plane z = 0 seen by ``cam``."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    rays = apply_matrix(np.linalg.inv(cam.K), np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)]))
    dirs = apply_matrix(cam.R.T, rays)  # world directions for z_cam = 1
    depth = -cam.center[2] / dirs[:, 2]
    return depth.reshape(H, W)


def _views(model: dict[str, Camera], gt: dict[str, Camera]) -> list[DenseView]:
    """Dense views of the model's cameras; depth (camera z) is the true one: the model's frame differs
    from the truth's by a similarity of scale 1."""
    return [DenseView(name, cam.R, cam.t, cam.K, _depth(gt[name]),
                      lambda x, cam=cam: apply_matrix(cam.K, x / x[:, 2:3])[:, :2], (W, H))
            for name, cam in model.items()]


def test_a_cloud_in_another_frame_reprojects_exactly_and_a_camera_error_shows_in_pixels():
    gt, points = _scene()
    # the model's frame: the ground truth moved by a similarity of scale 1 (depth maps unchanged)
    to_gt = Similarity(1.0, _rotation_y(20), np.array([0.3, -0.2, 1.0]))
    back = to_gt.inverse()
    model = {}
    for name, cam in gt.items():
        R = cam.R @ to_gt.R  # world-to-camera in the model frame: x_cam = R_gt (s R X + t) + t_gt
        t = cam.R @ to_gt.t + cam.t
        model[name] = Camera(K, R, t, W, H)
    model_points = back.apply(points)
    errors = reprojection_errors(model_points, _views(model, gt), gt, to_gt)
    assert len(errors) == 3 * len(points)  # every camera sees the whole grid
    assert np.max(errors) < 1e-6

    # the estimated camera of v2 is off by 0.2 degrees about its y axis: its observations move
    # by f tan(0.2 deg) = 1.05 px against the truth
    wrong = dict(model)
    cam = model["v2.jpg"]
    wrong["v2.jpg"] = Camera(K, _rotation_y(0.2) @ cam.R, _rotation_y(0.2) @ cam.t, W, H)
    errors = reprojection_errors(model_points, _views(wrong, gt), gt, to_gt)
    v2 = errors[2 * len(points):]
    assert np.allclose(np.median(v2), 300 * np.tan(np.radians(0.2)), rtol=0.05)
    assert np.max(errors[: 2 * len(points)]) < 1e-6


def test_occluded_and_unmeasured_views_do_not_count():
    gt, points = _scene()
    views = _views(gt, gt)
    views[0].depth[:] = 0  # v0 measured nothing
    views[1].depth *= 0.9  # v1 saw something 10 % nearer: an occluder
    errors = reprojection_errors(points, views, gt, Similarity(1.0, np.eye(3), np.zeros(3)))
    assert len(errors) == len(points)  # only v2 sees them


def test_observations_are_scaled_to_the_ground_truth_photo_size():
    gt, points = _scene()
    views = _views(gt, gt)
    for view in views:  # the model describes the photos at half size
        view.to_photo = lambda x, f=view.to_photo: f(x) / 2
        view.photo_size = (W // 2, H // 2)
    errors = reprojection_errors(points, views, gt, Similarity(1.0, np.eye(3), np.zeros(3)))
    assert np.max(errors) < 1e-6


def test_alignment_refined_on_observations_recovers_the_similarity():
    gt, points = _scene()
    truth = Similarity(1.7, _rotation_y(20), np.array([0.3, -0.2, 1.0]))
    model_points = truth.inverse().apply(points)
    observations = [(name, model_points, cam.project(points)[0]) for name, cam in gt.items()]
    # a start off by 3 degrees, 5 % in scale and 0.05 in position: pixels of error
    start = Similarity(1.7 * 1.05, _rotation_y(23), truth.t + 0.05)
    before = np.median(np.linalg.norm(gt["v0.jpg"].project(start.apply(model_points))[0] - observations[0][2], axis=1))
    refined = refine_alignment(observations, gt, start)
    assert before > 3
    assert np.allclose(refined.apply(model_points), points, atol=1e-6)
