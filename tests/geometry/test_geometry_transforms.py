"""Property tests of recon.geometry.transforms (poses, projection, quaternions, similarity)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from recon.geometry.transforms import (
    Similarity,
    align_similarity,
    apply_matrix,
    backproject,
    camera_center,
    compose_poses,
    invert_pose,
    project,
    qvec_to_rotmat,
    relative_pose,
    rotation_angle_deg,
    rotmat_to_qvec,
    umeyama,
    vector_angle_deg,
)

seeds = st.integers(min_value=0, max_value=2**32 - 1)


def random_pose(rng):
    return Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3) * 3


@given(seeds)
def test_compose_with_inverse_is_identity(seed):
    rng = np.random.default_rng(seed)
    R, t = random_pose(rng)
    for Rc, tc in (compose_poses((R, t), invert_pose(R, t)), compose_poses(invert_pose(R, t), (R, t))):
        np.testing.assert_allclose(Rc, np.eye(3), atol=1e-12)
        np.testing.assert_allclose(tc, 0, atol=1e-12)


@given(seeds)
def test_compose_applies_right_pose_first(seed):
    rng = np.random.default_rng(seed)
    a, b = random_pose(rng), random_pose(rng)
    X = rng.normal(size=3)
    R, t = compose_poses(a, b)
    np.testing.assert_allclose(R @ X + t, a[0] @ (b[0] @ X + b[1]) + a[1], atol=1e-9)
    # relative pose maps camera a coordinates to camera b coordinates
    Rr, tr = relative_pose(a, b)
    np.testing.assert_allclose(Rr @ (a[0] @ X + a[1]) + tr, b[0] @ X + b[1], atol=1e-9)


@given(seeds)
def test_camera_center_projects_to_origin(seed):
    R, t = random_pose(np.random.default_rng(seed))
    np.testing.assert_allclose(R @ camera_center(R, t) + t, 0, atol=1e-9)


@given(seeds, st.floats(0.2, 50.0))
def test_project_backproject_round_trip(seed, depth):
    rng = np.random.default_rng(seed)
    R, t = random_pose(rng)
    K = np.array([[500.0 + rng.uniform(0, 500), 0, 320.5], [0, 480.0, 240.25], [0, 0, 1]])
    uv = rng.uniform([0, 0], [640, 480], size=(20, 2))
    X = backproject(K, R, t, uv, np.full(20, depth))
    uv2, z = project(K, R, t, X)
    np.testing.assert_allclose(uv2, uv, atol=1e-6)
    np.testing.assert_allclose(z, depth, rtol=1e-9)


def test_project_pixel_convention():
    # a point on the optical axis lands on the principal point; with cx = W/2 that is the centre of
    # the image, e.g. the corner between the four middle pixels of an even-sized image (COLMAP)
    K = np.array([[100.0, 0, 2.0], [0, 100.0, 1.5], [0, 0, 1]])
    uv, z = project(K, np.eye(3), np.zeros(3), np.array([[0.0, 0.0, 5.0], [0.05, 0.0, 1.0]]))
    np.testing.assert_allclose(uv, [[2.0, 1.5], [7.0, 1.5]])
    np.testing.assert_allclose(z, [5.0, 1.0])


@given(seeds)
def test_quaternion_round_trip(seed):
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    q = q if q[0] >= 0 else -q
    R = qvec_to_rotmat(q)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(rotmat_to_qvec(R), q, atol=1e-9)
    # COLMAP's order (w, x, y, z) agrees with scipy's (x, y, z, w)
    np.testing.assert_allclose(R, Rotation.from_quat(np.r_[q[1:], q[0]]).as_matrix(), atol=1e-12)


def test_rotmat_to_qvec_near_180_degrees():
    R = Rotation.from_rotvec([0, np.pi - 1e-9, 0]).as_matrix()
    np.testing.assert_allclose(qvec_to_rotmat(rotmat_to_qvec(R)), R, atol=1e-9)


@given(seeds, st.floats(0.0, 179.0))
def test_rotation_angle(seed, angle):
    rng = np.random.default_rng(seed)
    R1 = Rotation.random(random_state=rng).as_matrix()
    axis = rng.normal(size=3)
    R2 = R1 @ Rotation.from_rotvec(np.radians(angle) * axis / np.linalg.norm(axis)).as_matrix()
    assert rotation_angle_deg(R1, R2) == pytest.approx(angle, abs=1e-5)


def test_vector_angle():
    assert vector_angle_deg([1, 0, 0], [0, 2, 0]) == pytest.approx(90)
    assert vector_angle_deg([1, 0, 0], [-3, 0, 0]) == pytest.approx(180)
    assert vector_angle_deg([1, 1e-9, 0], [1, 0, 0]) == pytest.approx(np.degrees(1e-9), rel=1e-3)


def random_similarity(rng):
    return Similarity(float(np.exp(rng.uniform(-2, 2))), Rotation.random(random_state=rng).as_matrix(),
                      rng.normal(size=3) * 10)


@given(seeds)
def test_umeyama_recovers_similarity_exactly(seed):
    rng = np.random.default_rng(seed)
    sim = random_similarity(rng)
    src = rng.normal(size=(10, 3))
    est = umeyama(src, sim.apply(src))
    assert est.s == pytest.approx(sim.s, rel=1e-9)
    np.testing.assert_allclose(est.R, sim.R, atol=1e-9)
    np.testing.assert_allclose(est.t, sim.t, atol=1e-8 * max(1, sim.s))


@given(seeds)
def test_similarity_inverse_and_pose_transfer(seed):
    rng = np.random.default_rng(seed)
    sim = random_similarity(rng)
    X = rng.normal(size=(5, 3))
    np.testing.assert_allclose(sim.inverse().apply(sim.apply(X)), X, atol=1e-9)
    # a camera moved with the world sees the same pixels, and its centre moves with the similarity
    R, t = random_pose(rng)
    R2, t2 = sim.apply_to_pose(R, t)
    K = np.diag([500.0, 500.0, 1.0])
    np.testing.assert_allclose(project(K, R2, t2, sim.apply(X))[0], project(K, R, t, X)[0], atol=1e-6)
    np.testing.assert_allclose(camera_center(R2, t2), sim.apply(camera_center(R, t)), atol=1e-8 * max(1, sim.s))


@pytest.mark.parametrize("threshold", [None, 0.05])
def test_robust_alignment_ignores_outliers(threshold):
    rng = np.random.default_rng(3)
    sim = random_similarity(rng)
    src = rng.normal(size=(40, 3))
    dst = sim.apply(src) + rng.normal(scale=1e-3 * sim.s, size=(40, 3))
    dst[:12] += rng.normal(scale=5 * sim.s, size=(12, 3))  # 30 % gross outliers
    plain, _ = align_similarity(src, dst)
    est, inliers = align_similarity(src, dst, robust=True, threshold=None if threshold is None else threshold * sim.s)
    assert not inliers[:12].any() and inliers[12:].all()
    assert est.s == pytest.approx(sim.s, rel=1e-2)
    assert rotation_angle_deg(est.R, sim.R) < 0.5
    assert abs(plain.s - sim.s) > 10 * abs(est.s - sim.s)


def test_apply_matrix_matches_matmul():
    rng = np.random.default_rng(0)
    M, X = rng.normal(size=(3, 3)), rng.normal(size=(7, 3))
    np.testing.assert_allclose(apply_matrix(M, X), X @ M.T)
    assert apply_matrix(M, X.astype(np.float32)).dtype == np.float32


@settings(max_examples=20)
@given(seeds)
def test_umeyama_without_scale(seed):
    rng = np.random.default_rng(seed)
    R, t = random_pose(rng)
    src = rng.normal(size=(6, 3))
    est = umeyama(src, src @ R.T + t, with_scale=False)
    assert est.s == 1.0
    np.testing.assert_allclose(est.R, R, atol=1e-9)
