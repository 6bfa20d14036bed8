"""Stereo pairs from a sparse model (pycolmap.Reconstruction): the registered photos' cameras, the
pair with the best baseline and overlap, and a depth range from the sparse points.

A pair is scored by the 3D points both photos see, weighted by how useful their median triangulation
angle is (:func:`recon.mvs.views.angle_weight`: best near 5 degrees); pairs whose baseline runs
mostly along the viewing direction, or whose cameras turn by more than MAX_ROTATION_DEG, are left
out (rectification would lose most of the overlap or resolution).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from recon.geometry.transforms import apply_matrix, camera_center, rotation_angle_deg
from recon.imaging.intrinsics import Intrinsics
from recon.stereo.calibration import StereoCalibration, from_poses
from recon.stereo.rectify import MIN_LATERAL

MIN_SHARED = 20
MAX_ROTATION_DEG = 30.0


@dataclass(frozen=True, eq=False)
class ModelView:
    """A registered photo of the model: name, intrinsics (COLMAP convention), world-to-camera pose and
    the ids of the 3D points it sees."""

    name: str
    camera: Intrinsics
    R: np.ndarray
    t: np.ndarray
    points: np.ndarray

    @property
    def center(self) -> np.ndarray:
        return camera_center(self.R, self.t)


@dataclass(frozen=True)
class PairScore:
    left: str
    right: str
    shared: int
    angle_deg: float
    score: float


def model_views(rec) -> dict[str, ModelView]:
    """The registered photos of a reconstruction, by name (a ValueError for a camera model that
    :class:`Intrinsics` does not know)."""
    views = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        pose = image.cam_from_world()
        ids = np.array(sorted(p.point3D_id for p in image.points2D if p.has_point3D()), dtype=np.int64)
        views[image.name] = ModelView(image.name, Intrinsics.from_pycolmap(rec.cameras[image.camera_id]),
                                      np.asarray(pose.rotation.matrix(), dtype=np.float64),
                                      np.asarray(pose.translation, dtype=np.float64), ids)
    return views


def pair_calibration(left: ModelView, right: ModelView) -> StereoCalibration:
    return from_poses(left.camera, (left.R, left.t), right.camera, (right.R, right.t))


def score_pair(rec, a: ModelView, b: ModelView) -> PairScore:
    """Shared points, their median triangulation angle and the pair's score (0 when unusable), with
    left and right ordered so that the right camera sits on the left's right."""
    from recon.mvs.views import angle_weight

    shared = np.intersect1d(a.points, b.points, assume_unique=True)
    if len(shared) == 0:
        return PairScore(a.name, b.name, 0, 0.0, 0.0)
    xyz = np.array([rec.points3D[int(i)].xyz for i in shared])
    ra, rb = xyz - a.center, xyz - b.center
    cos = np.einsum("ij,ij->i", ra, rb) / (np.linalg.norm(ra, axis=1) * np.linalg.norm(rb, axis=1))
    angle = float(np.degrees(np.median(np.arccos(np.clip(cos, -1.0, 1.0)))))
    offset = a.R @ (b.center - a.center)  # b's centre in a's camera frame
    lateral = math.hypot(offset[0], offset[1]) / max(np.linalg.norm(offset), 1e-300)
    usable = lateral >= MIN_LATERAL and rotation_angle_deg(a.R, b.R) <= MAX_ROTATION_DEG
    score = float(len(shared) * angle_weight(np.array(angle))) if usable else 0.0
    left, right = (a, b) if offset[0] >= 0 else (b, a)
    return PairScore(left.name, right.name, len(shared), angle, score)


def best_pair(rec, views: dict[str, ModelView], among: str | None = None) -> PairScore | None:
    """The best-scoring pair of registered photos (one of them ``among`` when given), or None.
    Every pair is looked at: fine for the few hundred photos of a model, quadratic beyond."""
    names = sorted(views)
    best = None
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if among is not None and among not in (a, b):
                continue
            if len(np.intersect1d(views[a].points, views[b].points, assume_unique=True)) < MIN_SHARED:
                continue
            pair = score_pair(rec, views[a], views[b])
            if pair.score > 0 and (best is None or pair.score > best.score):
                best = pair
    return best


def depth_range(rec, view: ModelView, margin: float) -> tuple[float, float] | None:
    """The depth range of the points ``view`` sees: 1st percentile / (1 + margin) to the 99th x
    (1 + margin); None with fewer than MIN_SHARED points in front of it."""
    if len(view.points) == 0:
        return None
    xyz = np.array([rec.points3D[int(i)].xyz for i in view.points])
    z = (apply_matrix(view.R, xyz) + view.t)[:, 2]
    z = z[z > 0]
    if len(z) < MIN_SHARED:
        return None
    low, high = np.percentile(z, [1, 99])
    return float(low / (1 + margin)), float(high * (1 + margin))
