"""Reprojection error of a fused point cloud into ground-truth cameras (real photo sets, no true surface).

A fused point stands where the photos saw the surface: through the estimated camera of a view that
sees it, it projects onto the pixel where that view observed it (fusion only merges pixels within
``max_reproj_error`` of that projection). Moved into the ground truth's frame by the similarity that
aligns the model's cameras to the true ones, the same point projected through the TRUE camera should
land on that pixel; the distance, in the original photo's pixels, is its reprojection error. It sums
the camera errors, the alignment and the depth errors (a point off the surface along a view's ray
lands elsewhere in the other views that see it).

The alignment starts from the robust similarity on camera centres and is then refined to minimise
the reprojection error of the SPARSE model's observations (its 3D points and the keypoints that see
them) in the true cameras: the centres alone leave a rotation of the whole model free within their
noise, which at 2,800 px of focal length is pixels (fountain_p11: sparse median 1.7 px on centres,
0.8 px refined). The fused cloud plays no part in the alignment it is measured with.

A view sees a point when the point is in front of it, inside its depth map, and agrees with the depth
the view itself measured there within ``depth_tolerance`` (relative): occluded views do not count.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from recon.eval.groundtruth import Camera
from recon.geometry.transforms import Similarity, apply_matrix


@dataclass
class DenseView:
    """One view of a dense reconstruction, in the model's frame."""

    name: str
    R: np.ndarray  # world-to-camera rotation (model frame)
    t: np.ndarray
    K: np.ndarray  # pinhole intrinsics of the depth map (pixel centres at +0.5)
    depth: np.ndarray  # camera z, 0 where the view measured nothing
    #: camera-frame points (N, 3) -> pixels (N, 2) in the original photo (its distortion included)
    to_photo: Callable[[np.ndarray], np.ndarray]
    photo_size: tuple[int, int]  # (width, height) of the photo the estimated camera describes


def reprojection_errors(points: np.ndarray, views: list[DenseView], gt: dict[str, Camera],
                        to_gt: Similarity, depth_tolerance: float = 0.01) -> np.ndarray:
    """Pixel errors, one per (point, view that sees it) with a ground-truth camera, in the ground-truth
    photo's pixels; ``points`` are in the model's frame, ``to_gt`` maps them to the ground truth's."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    moved = to_gt.apply(points)
    errors = []
    for view in views:
        cam = gt.get(view.name)
        if cam is None:
            continue
        x_cam = apply_matrix(view.R, points) + view.t
        seen = _sees(view, x_cam, depth_tolerance)
        if not seen.any():
            continue
        observed = view.to_photo(x_cam[seen])
        if cam.width and cam.height:  # the true camera may describe the photo at another size
            observed = observed * [cam.width / view.photo_size[0], cam.height / view.photo_size[1]]
        truth, _ = cam.project(moved[seen])
        errors.append(np.linalg.norm(truth - observed, axis=1))
    return np.concatenate(errors) if errors else np.zeros(0)


def refine_alignment(observations: list[tuple[str, np.ndarray, np.ndarray]], gt: dict[str, Camera],
                     start: Similarity, robust_px: float = 2.0) -> Similarity:
    """The similarity (model -> ground truth) minimising the reprojection error of ``observations``
    in the true cameras, starting from ``start``: per view name, model-frame points (N, 3) and the
    pixels (N, 2) they were observed at. Robust (soft L1 beyond ``robust_px``)."""
    from scipy.optimize import least_squares
    from scipy.spatial.transform import Rotation

    groups = [(gt[name], np.asarray(X, float), np.asarray(xy, float)) for name, X, xy in observations
              if name in gt and len(X)]

    def similarity(p: np.ndarray) -> Similarity:
        return Similarity(float(np.exp(p[6])), Rotation.from_rotvec(p[:3]).as_matrix(), p[3:6])

    def residuals(p: np.ndarray) -> np.ndarray:
        sim = similarity(p)
        return np.concatenate([(cam.project(sim.apply(X))[0] - xy).ravel() for cam, X, xy in groups])

    p0 = np.r_[Rotation.from_matrix(start.R).as_rotvec(), start.t, np.log(start.s)]
    return similarity(least_squares(residuals, p0, loss="soft_l1", f_scale=robust_px).x)


def _sees(view: DenseView, x_cam: np.ndarray, tolerance: float) -> np.ndarray:
    height, width = view.depth.shape
    z = x_cam[:, 2]
    front = z > 0
    uv = np.full((len(z), 2), -1.0)
    uv[front] = apply_matrix(view.K, x_cam[front] / z[front, None])[:, :2]
    col, row = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = front & (col >= 0) & (row >= 0) & (col < width) & (row < height)
    seen = np.zeros(len(z), dtype=bool)
    measured = view.depth[row[inside], col[inside]]
    seen[inside] = (measured > 0) & (np.abs(measured - z[inside]) <= tolerance * z[inside])
    return seen
