"""Rigid and similarity transforms, camera poses and projection in COLMAP's conventions.

A pose ``(R, t)`` maps world to camera: ``x_cam = R @ X + t``; the camera centre is ``-R.T @ t``.
Pixels follow COLMAP: ``(u, v) = (K @ x_cam)[:2] / z`` where the centre of the top-left pixel is at
(0.5, 0.5), so an image of width W spans u in [0, W]. Quaternions are COLMAP's ``qvec`` order
(w, x, y, z), normalised with w >= 0. Angles are returned in degrees.

Batched products go through :func:`apply_matrix` (einsum, no BLAS): with OpenBLAS threads on a busy
machine, ``(N, 3) @ (3, 3)`` was measured 20-100x slower than einsum (thread spin-waiting).
"""

from __future__ import annotations

import dataclasses

import numpy as np

Pose = tuple[np.ndarray, np.ndarray]


def apply_matrix(M: np.ndarray, X: np.ndarray) -> np.ndarray:
    """``X @ M.T`` for points (..., k) and a small matrix (m, k), without BLAS (see the module doc)."""
    X = np.asarray(X)
    return np.einsum("ij,...j->...i", np.asarray(M, dtype=X.dtype if X.dtype.kind == "f" else float), X)


def invert_pose(R: np.ndarray, t: np.ndarray) -> Pose:
    """The inverse of ``x -> R x + t``: ``(R.T, -R.T t)``."""
    R = np.asarray(R, dtype=float)
    return R.T, -R.T @ np.asarray(t, dtype=float)


def compose_poses(a: Pose, b: Pose) -> Pose:
    """The pose ``x -> a(b(x))``: apply ``b`` first, then ``a``."""
    Ra, ta = (np.asarray(v, dtype=float) for v in a)
    Rb, tb = (np.asarray(v, dtype=float) for v in b)
    return Ra @ Rb, Ra @ tb + ta


def relative_pose(a: Pose, b: Pose) -> Pose:
    """The pose of camera ``b`` in camera ``a``'s frame: maps ``a``-camera to ``b``-camera coordinates."""
    return compose_poses(b, invert_pose(*a))


def camera_center(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Camera centre in world coordinates of the world-to-camera pose ``(R, t)``."""
    return -np.asarray(R, dtype=float).T @ np.asarray(t, dtype=float)


def project(K: np.ndarray, R: np.ndarray, t: np.ndarray, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points ``X`` (N, 3) to pixels (N, 2) and camera depths z (N,).

    Points behind the camera (z <= 0) get non-finite or meaningless pixels: filter on ``z > 0``.
    """
    X = np.asarray(X, dtype=float).reshape(-1, 3)
    xc = apply_matrix(R, X) + np.asarray(t, dtype=float)
    z = xc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = apply_matrix(K, xc)
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


def backproject(K: np.ndarray, R: np.ndarray, t: np.ndarray, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points (N, 3) seen at pixels ``uv`` (N, 2) with camera depth ``depth`` (N,) (z, not range)."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    rays = apply_matrix(np.linalg.inv(np.asarray(K, dtype=float)), np.column_stack([uv, np.ones(len(uv))]))
    xc = rays * np.asarray(depth, dtype=float).reshape(-1, 1)
    return apply_matrix(np.asarray(R, dtype=float).T, xc - np.asarray(t, dtype=float))


def qvec_to_rotmat(qvec: np.ndarray) -> np.ndarray:
    """Rotation matrix of a quaternion in COLMAP order (w, x, y, z); the quaternion need not be unit."""
    w, x, y, z = np.asarray(qvec, dtype=float) / np.linalg.norm(qvec)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rotmat_to_qvec(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z), w >= 0, of a rotation matrix (Bar-Itzhack's eigenvector method,
    which stays accurate for any rotation and tolerates slightly non-orthogonal input)."""
    (rxx, ryx, rzx), (rxy, ryy, rzy), (rxz, ryz, rzz) = np.asarray(R, dtype=float)
    Km = np.array([
        [rxx - ryy - rzz, 0, 0, 0],
        [ryx + rxy, ryy - rxx - rzz, 0, 0],
        [rzx + rxz, rzy + ryz, rzz - rxx - ryy, 0],
        [ryz - rzy, rzx - rxz, rxy - ryx, rxx + ryy + rzz],
    ]) / 3.0
    vals, vecs = np.linalg.eigh(Km)
    q = vecs[[3, 0, 1, 2], np.argmax(vals)]
    return -q if q[0] < 0 else q


def rotation_angles_deg(R: np.ndarray) -> np.ndarray:
    """Rotation angles in degrees of rotation matrices (..., 3, 3), accurate near 0 and 180 degrees
    (atan2 of the skew and trace parts instead of arccos of the trace alone)."""
    R = np.asarray(R, dtype=float)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    skew = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    return np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1) / 2.0, cos))


def rotation_angle_deg(R1: np.ndarray, R2: np.ndarray) -> float:
    """Angle in degrees of the rotation ``R1^T R2`` that takes ``R1`` to ``R2``."""
    return float(rotation_angles_deg(np.asarray(R1, dtype=float).T @ np.asarray(R2, dtype=float)))


def vector_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in degrees between two non-zero vectors (robust near 0 and 180 degrees)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), np.dot(a, b))))


@dataclasses.dataclass(frozen=True, eq=False)
class Similarity:
    """The similarity ``X -> s R X + t`` (scale ``s`` > 0, rotation ``R``, translation ``t``)."""

    s: float
    R: np.ndarray
    t: np.ndarray

    def apply(self, X: np.ndarray) -> np.ndarray:
        """Transform points (N, 3) or one point (3,)."""
        X = np.asarray(X, dtype=float)
        return self.s * apply_matrix(self.R, X) + self.t

    def inverse(self) -> Similarity:
        return Similarity(1.0 / self.s, self.R.T, -self.R.T @ self.t / self.s)

    def apply_to_pose(self, R: np.ndarray, t: np.ndarray) -> Pose:
        """The world-to-camera pose, in the transformed world, of the camera ``(R, t)``.

        The camera sees the transformed world exactly as it saw the old one (same pixels); its
        centre moves to ``apply(centre)``.
        """
        R_new = np.asarray(R, dtype=float) @ self.R.T
        return R_new, self.s * np.asarray(t, dtype=float) - R_new @ self.t


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity (Umeyama 1991) with ``dst ~ s R src + t`` for paired points (N, 3), N >= 3."""
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    if len(src) != len(dst) or len(src) < 3:
        raise ValueError(f"umeyama needs >= 3 paired points, got {len(src)} and {len(dst)}")
    return weighted_umeyama(src, dst, np.ones(len(src)), with_scale)


def weighted_umeyama(src: np.ndarray, dst: np.ndarray, weights: np.ndarray, with_scale: bool = True) -> Similarity:
    """Least-squares similarity ``dst ~ s R src + t`` minimising sum w |dst - (s R src + t)|^2 (Umeyama
    1991 with weights; :func:`umeyama` with equal weights)."""
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    w = np.asarray(weights, dtype=float) / np.sum(weights)
    mu_s, mu_d = w @ src, w @ dst
    xs, xd = src - mu_s, dst - mu_d
    U, D, Vt = np.linalg.svd((xd * w[:, None]).T @ xs)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    var_s = w @ (xs**2).sum(axis=1)
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale and var_s > 0 else 1.0
    return Similarity(s, R, mu_d - s * R @ mu_s)


def align_similarity(src: np.ndarray, dst: np.ndarray, *, robust: bool = False,
                     threshold: float | None = None, iterations: int = 500,
                     seed: int = 0) -> tuple[Similarity, np.ndarray]:
    """Similarity with ``dst ~ s R src + t``, and the boolean mask of points used for the final fit.

    ``robust=False``: Umeyama on all points. ``robust=True``: random minimal samples of 3 points give
    hypotheses, scored by inlier count within ``threshold`` (RANSAC) or, when ``threshold`` is None, by
    the median residual (least median of squares, no threshold needed); the best one is refit with
    Umeyama on its inliers (residual <= threshold, or <= 2.5 robust sigmas for LMedS).
    """
    src = np.asarray(src, dtype=float).reshape(-1, 3)
    dst = np.asarray(dst, dtype=float).reshape(-1, 3)
    n = len(src)
    if not robust or n <= 3:
        return umeyama(src, dst), np.ones(n, dtype=bool)
    rng = np.random.default_rng(seed)
    scale = np.linalg.norm(src - src.mean(0), axis=1).max()
    best, best_score = None, None
    for _ in range(iterations):
        idx = rng.choice(n, 3, replace=False)
        a, b, c = src[idx]
        if np.linalg.norm(np.cross(b - a, c - a)) < 1e-9 * scale**2:
            continue  # collinear sample: rotation about the line is undetermined
        sim = umeyama(src[idx], dst[idx])
        res = np.linalg.norm(sim.apply(src) - dst, axis=1)
        score = -np.count_nonzero(res <= threshold) if threshold is not None else np.median(res)
        if best_score is None or score < best_score:
            best, best_score = sim, score
    if best is None:
        return umeyama(src, dst), np.ones(n, dtype=bool)
    res = np.linalg.norm(best.apply(src) - dst, axis=1)
    limit = threshold if threshold is not None else 2.5 * 1.4826 * np.median(res)
    inliers = res <= max(limit, 1e-12 * scale)
    if inliers.sum() < 3:
        return best, inliers
    return umeyama(src[inliers], dst[inliers]), inliers


def up_direction(rotations: np.ndarray, centers: np.ndarray) -> np.ndarray:
    """The world direction the photos hold as "up": minus the mean of the cameras' image-down axes
    (people hold cameras roughly level); the normal of the cameras' plane when that mean is weak."""
    if len(rotations) == 0:
        return np.array([0.0, 0.0, 1.0])
    down = rotations[:, 1, :].mean(axis=0)
    if np.linalg.norm(down) > 0.3:
        return -down / np.linalg.norm(down)
    if len(centers) >= 3:
        normal = np.linalg.svd(centers - centers.mean(axis=0))[2][2]
        return normal if normal @ -down >= 0 else -normal
    return np.array([0.0, 0.0, 1.0])


def axis_angle_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """The rotation by ``angle`` (radians) about ``axis`` (Rodrigues' formula)."""
    k = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def level_rotation(up: np.ndarray) -> np.ndarray:
    """The smallest rotation taking the unit vector ``up`` to +Z (a world whose up is +Z, as ENU)."""
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    axis = np.cross(up, z)
    s, c = np.linalg.norm(axis), float(up @ z)
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    return axis_angle_rotation(axis, float(np.arctan2(s, c)))
