"""Placing one new photo: 2D-3D correspondences, absolute pose by RANSAC, and whether to trust it.

The pose is COLMAP's (``pycolmap.estimate_and_refine_absolute_pose``): P3P (P4Pf when the focal
length is estimated) in LO-RANSAC, then a non-linear refinement of the inliers' reprojection error.
A photo is refused, with the reason, when it has fewer than ``min_inliers`` inliers, or they are
less than ``min_inlier_ratio`` of its matches (COLMAP's registration thresholds), or an estimated
focal length is implausible: a photo of another scene gets a few chance matches, and RANSAC with
a free focal length fits a handful of them.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from recon.geometry.transforms import camera_center, rotmat_to_qvec
from recon.localize.correspondences import correspondences
from recon.localize.intrinsics import Intrinsics, PhotoCamera, choose_intrinsics
from recon.localize.options import LocalizeOptions
from recon.localize.reference import Reference

log = logging.getLogger(__name__)

#: plausible estimated focal lengths, in units of the photo's longest side (fields of view ~140 to ~6 deg)
FOCAL_RANGE = (0.2, 10.0)


@dataclass(frozen=True)
class Photo:
    """A new photo: its name, camera record and SIFT features (keypoints x, y, ... in its pixels)."""

    name: str
    camera: PhotoCamera
    keypoints: np.ndarray
    descriptors: np.ndarray


@dataclass
class Placement:
    """The outcome for one photo. ``R``, ``t``: world-to-camera (``x_cam = R X + t``), None when refused."""

    name: str
    placed: bool
    reason: str
    matches: int = 0
    inliers: int = 0
    retrieved: list[str] = field(default_factory=list)
    intrinsics: str = ""
    camera_model: str = ""
    width: int = 0
    height: int = 0
    params: list[float] = field(default_factory=list)
    R: np.ndarray | None = None
    t: np.ndarray | None = None

    @property
    def centre(self) -> np.ndarray | None:
        return None if self.R is None else camera_center(self.R, self.t)

    def to_json(self) -> dict:
        out = {"name": self.name, "placed": self.placed, "reason": self.reason, "matches": self.matches,
               "inliers": self.inliers}
        if self.R is not None:
            out.update(qvec=rotmat_to_qvec(self.R).tolist(), tvec=np.asarray(self.t).tolist(),
                       centre=self.centre.tolist())
        if self.camera_model:
            out["camera"] = {"model": self.camera_model, "width": self.width, "height": self.height,
                             "params": list(self.params)}
        out.update(intrinsics=self.intrinsics, retrieved=self.retrieved)
        return out


def place(photo: Photo, reference: Reference, retrieved: list[int], options: LocalizeOptions,
          seed: int = 0) -> Placement:
    """Localize ``photo`` against ``reference`` through the registered images ``retrieved``."""
    result = Placement(photo.name, False, "", retrieved=[reference.name(i) for i in retrieved])
    intrinsics = choose_intrinsics(photo.camera, reference, options)
    if isinstance(intrinsics, str):
        result.reason = intrinsics
        return result
    result.intrinsics = intrinsics.source
    kp_idx, point_ids = correspondences(reference, retrieved, photo.descriptors, options)
    result.matches = len(kp_idx)
    if len(kp_idx) < options.min_inliers:
        result.reason = (f"too few 2D-3D matches: {len(kp_idx)} with the {len(retrieved)} most similar reference "
                         f"images (need {options.min_inliers}); is it a photo of the reference's scene?")
        _set_camera(result, intrinsics.camera)
        return result
    points2D = photo.keypoints[kp_idx, :2].astype(np.float64)
    estimate = _estimate(points2D, reference.points3D(point_ids), intrinsics, options, seed)
    camera = intrinsics.camera  # estimate_and_refine_absolute_pose updates an estimated focal length in place
    _set_camera(result, camera)
    if estimate is None:
        result.reason = f"no pose: RANSAC found no consistent pose among {len(kp_idx)} 2D-3D matches"
        return result
    result.inliers = int(estimate["num_inliers"])
    ratio = result.inliers / len(kp_idx)
    size = max(camera.width, camera.height)
    if result.inliers < options.min_inliers:
        result.reason = (f"too few inliers: {result.inliers} of {len(kp_idx)} 2D-3D matches (need "
                         f"{options.min_inliers})")
    elif ratio < options.min_inlier_ratio:
        result.reason = (f"inlier ratio too low: {result.inliers} of {len(kp_idx)} 2D-3D matches ({ratio:.2f}, "
                         f"need {options.min_inlier_ratio:g})")
    elif intrinsics.estimate_focal and not FOCAL_RANGE[0] <= camera.mean_focal_length() / size <= FOCAL_RANGE[1]:
        result.reason = (f"implausible estimated focal length {camera.mean_focal_length():.0f} px for a "
                         f"{camera.width}x{camera.height} photo")
    else:
        pose = estimate["cam_from_world"]
        result.placed = True
        result.R, result.t = pose.rotation.matrix(), np.asarray(pose.translation, dtype=np.float64)
    return result


def _estimate(points2D: np.ndarray, points3D: np.ndarray, intrinsics: Intrinsics, options: LocalizeOptions,
              seed: int) -> dict | None:
    import pycolmap

    est = pycolmap.AbsolutePoseEstimationOptions()
    est.estimate_focal_length = intrinsics.estimate_focal
    est.ransac.max_error = options.max_error
    est.ransac.random_seed = seed
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.refine_focal_length = intrinsics.estimate_focal
    ref.refine_extra_params = False
    return pycolmap.estimate_and_refine_absolute_pose(points2D, points3D, intrinsics.camera, est, ref)


def _set_camera(result: Placement, camera) -> None:
    result.camera_model = camera.model.name
    result.width, result.height = int(camera.width), int(camera.height)
    result.params = [float(p) for p in camera.params]
