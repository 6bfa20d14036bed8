"""Pose metrics: AUC definition, gauge invariance, known perturbations, unregistered images."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recon.eval.groundtruth import Camera
from recon.eval.poses import pose_auc, pose_metrics
from recon.geometry.transforms import (
    Similarity,
    camera_center,
    relative_pose,
    rotation_angle_deg,
    vector_angle_deg,
)
from recon.synth import scene_cameras


@pytest.fixture(scope="module")
def gt():
    return scene_cameras(20, 640, 480, seed=0)[0]


def as_est(cams):
    return {n: (c.R.copy(), c.t.copy()) for n, c in cams.items()}


def test_perfect_estimate(gt):
    m = pose_metrics(as_est(gt), gt)
    assert m["registered"] == m["total"] == 20
    assert m["pairs"] == 190
    for k in ("auc@1", "auc@3", "auc@5"):
        assert m[k] == pytest.approx(100.0, abs=1e-6)
    assert m["median_center_error"] == pytest.approx(0.0, abs=1e-9)
    assert m["median_center_error_rel"] == pytest.approx(0.0, abs=1e-9)


def test_gauge_invariance(gt):
    sim = Similarity(3.7, Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix(),
                     np.array([5.0, -2.0, 11.0]))
    est = {n: sim.apply_to_pose(c.R, c.t) for n, c in gt.items()}
    m = pose_metrics(est, gt)
    for k in ("auc@1", "auc@3", "auc@5"):
        assert m[k] == pytest.approx(100.0, abs=1e-6)
    assert m["median_center_error"] < 1e-9


def reference_errors(est, gt):
    """Pair errors computed pair by pair with the scalar helpers (an independent path)."""
    names = sorted(gt)
    out = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            Rg, tg = relative_pose((gt[a].R, gt[a].t), (gt[b].R, gt[b].t))
            Re, te = relative_pose(est[a], est[b])
            out.append(max(rotation_angle_deg(Re, Rg), vector_angle_deg(te, tg)))
    return np.array(out)


def test_rotation_perturbation_of_known_size(gt):
    # turn every camera by 2 degrees about its own centre (random axes): a pair's relative rotation
    # is then off by at most 4 degrees and its relative translation direction by at most 2
    est = {}
    rng = np.random.default_rng(0)
    for n, c in gt.items():
        axis = rng.normal(size=3)
        R = Rotation.from_rotvec(np.radians(2.0) * axis / np.linalg.norm(axis)).as_matrix() @ c.R
        est[n] = (R, -R @ c.center)
    errors = reference_errors(est, gt)
    assert errors.max() <= 4.0 + 1e-9 and 1.0 < np.median(errors) < 4.0
    m = pose_metrics(est, gt)
    for thr in (1, 3, 5):
        assert m[f"auc@{thr}"] == pytest.approx(pose_auc(errors, [thr])[0])
    assert m["auc@1"] < 10.0
    assert 100 * (1 - 4 / 5) <= m["auc@5"] < 100 * (1 - 1 / 5)
    assert m["median_center_error"] < 1e-9  # centres untouched


def test_single_camera_translation_error(gt):
    # move one camera sideways: only its 19 pairs get an error
    names = sorted(gt)
    est = as_est(gt)
    c = gt[names[3]]
    moved = c.center + 0.3 * c.R[0]
    est[names[3]] = (c.R, -c.R @ moved)
    errors = reference_errors(est, gt)
    assert np.count_nonzero(errors > 1e-6) == 19 and 1.0 < errors.max() < 20.0
    m = pose_metrics(est, gt)
    for thr in (1, 3, 5):
        assert m[f"auc@{thr}"] == pytest.approx(pose_auc(errors, [thr])[0])
    assert m["auc@5"] >= 100.0 * 171 / 190 - 1e-9
    assert m["median_center_error"] == pytest.approx(0.0, abs=1e-6)  # robust to one moved camera


def test_unregistered_images_count_180(gt):
    names = sorted(gt)
    est = {n: (gt[n].R, gt[n].t) for n in names[:15]}  # 5 of 20 missing
    m = pose_metrics(est, gt)
    assert m["registered"] == 15 and m["total"] == 20
    good_share = (15 * 14 / 2) / 190
    for k in ("auc@1", "auc@3", "auc@5"):
        assert m[k] == pytest.approx(100.0 * good_share, abs=1e-6)
    assert m["median_center_error"] == pytest.approx(0.0, abs=1e-9)
    # fewer than 3 registered: no centre alignment
    m2 = pose_metrics({n: (gt[n].R, gt[n].t) for n in names[:2]}, gt)
    assert np.isnan(m2["median_center_error"]) and m2["registered"] == 2
    assert m2["auc@5"] == pytest.approx(100.0 / 190, abs=1e-6)
    # estimates for images outside the ground truth are ignored
    m3 = pose_metrics({**as_est(gt), "extra.jpg": (np.eye(3), np.zeros(3))}, gt)
    assert m3["registered"] == 20


def test_center_error_scaled_to_gt_units(gt):
    # estimated in another gauge with every centre off by a known 0.1 (GT units) along a fixed
    # per-camera direction perpendicular to the orbit plane, alternating sign
    sim = Similarity(0.2, np.eye(3), np.array([1.0, 2.0, 3.0]))
    est = {}
    for i, (n, c) in enumerate(sorted(gt.items())):
        centre = c.center + np.array([0, 0, 0.1 if i % 2 else -0.1])
        R = c.R
        R2, t2 = sim.apply_to_pose(R, -R @ centre)
        est[n] = (R2, t2)
    m = pose_metrics(est, gt)
    assert m["median_center_error"] == pytest.approx(0.1, rel=0.05)
    centres = np.array([camera_center(c.R, c.t) for c in gt.values()])
    spread = np.median(np.linalg.norm(centres - centres.mean(0), axis=1))
    assert m["median_center_error_rel"] == pytest.approx(m["median_center_error"] / spread)


def test_auc_matches_glue_factory_definition():
    errors = np.array([0.5, 1.5, 2.5, 10.0])
    # recall steps 0.25 at each error: area under the step-with-trapezoids curve up to 3
    # points (0,0) (0.5,.25) (1.5,.5) (2.5,.75) (3,.75)
    area = 0.5 * 0.25 / 2 + 1.0 * (0.25 + 0.5) / 2 + 1.0 * (0.5 + 0.75) / 2 + 0.5 * 0.75
    assert pose_auc(errors, [3.0])[0] == pytest.approx(100 * area / 3)
    assert pose_auc(np.zeros(5), [1.0])[0] == pytest.approx(100.0)
    assert pose_auc(np.full(5, 180.0), [5.0])[0] == 0.0


def test_single_image_has_no_pairs():
    cam = Camera(np.eye(3), np.eye(3), np.zeros(3), 10, 10)
    m = pose_metrics({"a": (np.eye(3), np.zeros(3))}, {"a": cam})
    assert m["pairs"] == 0 and m["registered"] == 1 and np.isnan(m["auc@5"])


def test_cameras_in_a_line_are_aligned_about_their_line_too():
    """A walk: camera centres on one line say nothing about the rotation about it; the cameras'
    axes do (align_cameras), so the recovered similarity maps the model's surface where it belongs."""
    from recon.eval.workspace import align_cameras
    from recon.geometry.transforms import qvec_to_rotmat

    rng = np.random.default_rng(3)
    look = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # camera x = world x, looking along world +y
    truth = [(look, -look @ np.array([k, 0.0, 1.5])) for k in range(10)]
    rot = qvec_to_rotmat(np.array([0.9, 0.3, -0.2, 0.25]) / np.linalg.norm([0.9, 0.3, -0.2, 0.25]))
    scale, shift = 0.5, np.array([3.0, -1.0, 2.0])
    est = []  # the same cameras in another frame: X_est = scale * rot @ X_true + shift
    for R, t in truth:
        centre = -R.T @ t
        R_est = R @ rot.T
        est.append((R_est, -R_est @ (scale * rot @ centre + shift + rng.normal(0, 1e-4, 3))))
    sim = align_cameras(est, truth)
    point = np.array([[4.0, 6.0, 0.0]])  # on the facade the walk faces, off the cameras' line
    assert np.linalg.norm(sim.apply(scale * point @ rot.T + shift) - point) < 1e-2


def test_workspace_alignment_is_refined_on_the_sparse_points(tmp_path):
    """The model's cameras carry pose noise, its sparse points and their keypoints are exact: the
    alignment on camera centres and axes is off by the noise, the refined one (reprojection of the
    sparse points into the true cameras) recovers the model's frame (recon.eval.workspace)."""
    import pycolmap

    from recon.eval.workspace import (
        _estimated_poses,
        _load_gt,
        _sparse_model,
        align_cameras,
        model_to_ground_truth,
    )
    from recon.geometry.transforms import qvec_to_rotmat
    from recon.mvs.gt_workspace import points_from_depths
    from recon.mvs.views import ViewCamera
    from recon.synth import render_scene

    scene = render_scene(tmp_path / "scene", views=6, width=160, height=120, seed=3)
    truth = scene.cameras()
    names = scene.image_names
    cams = [ViewCamera(n, truth[n].K, truth[n].R, truth[n].t, 160, 120) for n in names]
    rec = points_from_depths(cams, [scene.depth(n) for n in names], points_per_image=200)
    to_model = Similarity(0.5, qvec_to_rotmat(np.array([0.9, 0.3, -0.2, 0.25]) / np.linalg.norm([0.9, 0.3, -0.2, 0.25])),
                          np.array([3.0, -1.0, 2.0]))
    rng = np.random.default_rng(0)
    for point in rec.points3D.values():
        point.xyz = to_model.apply(point.xyz[None])[0]
    for image in rec.images.values():
        R, t = to_model.apply_to_pose(truth[image.name].R, truth[image.name].t)
        q = np.r_[1.0, rng.normal(0, 0.01, 3)]
        R_noisy = qvec_to_rotmat(q / np.linalg.norm(q)) @ R
        centre = -R.T @ t + rng.normal(0, 0.02, 3)
        rec.frames[image.frame_id].rig_from_world = pycolmap.Rigid3d(pycolmap.Rotation3d(R_noisy), -R_noisy @ centre)
    (tmp_path / "ws" / "sparse" / "0").mkdir(parents=True)
    rec.write(tmp_path / "ws" / "sparse" / "0")

    probe = np.array([p.xyz for p in rec.points3D.values()])
    expected = to_model.inverse().apply(probe)
    gt_cams = _load_gt(scene.root)
    est = _estimated_poses(_sparse_model(tmp_path / "ws"), gt_cams)
    start = align_cameras([est[n] for n in sorted(est)], [(gt_cams[n].R, gt_cams[n].t) for n in sorted(est)])
    refined = model_to_ground_truth(tmp_path / "ws", scene.root)
    extent = np.ptp(expected, axis=0).max()
    assert np.median(np.linalg.norm(start.apply(probe) - expected, axis=1)) > 2e-3 * extent
    assert np.median(np.linalg.norm(refined.apply(probe) - expected, axis=1)) < 1e-4 * extent
