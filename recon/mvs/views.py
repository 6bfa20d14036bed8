"""Choose, for every reference image, its source views and depth range from the sparse model.

A source view must see at least ``min_points`` of the reference's 3D points under at least
``min_triangulation_angle``, at a resolution (ratio of depth / focal length, median over those
points) within ``max_scale_ratio`` of the reference's. It is then scored by the points the two views
share in tracks (matched features: evidence that the photos look alike there), each weighted by how
useful its triangulation angle is (the piecewise Gaussian of MVSNet's view selection: peak at 5 deg,
narrow below, wide above).

A view sees a point when the point's track holds it, or when the point projects into the view's
frame, in front of it, and none of the view's own nearest sparse points in the image (within 5 % of
its longer side) lies at under 0.8 times the point's depth (the point is not hidden behind what the
view itself triangulated). Tracks alone undercount where the sparse model is thin: on the zoo's
walkaround (72-101 points per view, photos 20-30 degrees apart round a corner) the next photo of the
walk, which sees 46 % of view 27's surface, tracked 7 of its points and was no source of it. Only
views sharing at least one tracked point with the reference are tried, so the cost follows the
covisibility graph, not the square of the view count. Points seen by projection alone do not score:
counted as well, on the zoo's street_forward (a forward walk) the views behind each photo, which see
all of its points from farther away, outranked the views ahead, and its fused F@0.2 % fell .806 ->
.761 (docs/DECISIONS.md).

The depth range runs from the 1st percentile of the depths of the points the reference observes,
/ (1 + margin) / ``near_reach``, to the depth of the farthest sparse point in front of it that projects
into its image, observed by it or not, whose track holds at least three photos,
* (1 + margin) * ``far_reach``. Far ground seen at a grazing angle gives the view that looks along it few
matched features, while other views triangulate it: on the zoo's far_field at 320x240 the 99th percentile
of the view's own points left 48 % of the observable surface beyond the range, the farthest point in view
1 %. A far bound costs little: PatchMatch samples depths uniformly in inverse depth, and [1/far, 1/near]
grew by 9 % (far_field) and 22 % (transient_car); the near bound, which sets that interval's scale, stays
on the view's own points (a percentile: one stray near point would spread the samples). A point only two
photos matched does not count: the zoo's aerial_grid held 30-40 such points in each view's frame at 11 to
17 times the ground's depth, and facade_walk some at 16 to 25 times its facade's. In ranges that deep the
depth maps agreed on points far below aerial_grid's ground (to 120 units under a scene 116 across; 95 %
of them within 11 once these points no longer count), and its mesh F@0.2 % rose .703 -> .747 without them
(docs/DECISIONS.md). The view's own points count no differently: only where fewer than ``min_points``
such points lie in its image does the 99th percentile of its own points' depths set the bound. Where a
corner photo of a survey shares much of its ground with one other photo, more than 1 % of its own points
can be two-photo mismatches far below the ground: two of aerial_grid's views had ranges 7 and 9 times
their deepest true depth, and their depth maps held 43 % and 67 % of their surface (66 % and 81 % with
these points left out).
The near bound reaches ``near_reach`` (3) times nearer than the view's own points because SfM
triangulates little of what stands close in front of the photos: seen from few of them, at wide angles,
its features do not make tracks. On the zoo's walkaround a tree and a bin 2 m from the camera filled up
to 35 % of a view, and no sparse point lay nearer than 5.6 m in it: 10 of its 29 views had 25-35 % of
their pixels in front of a range that started behind them (docs/DECISIONS.md).
A view then reaches as far as its sources reach: its far bound is the largest of its own and its
sources'. A view looking along far ground can miss sparse points its sources triangulated there
outside its own frame, as at the edge of its image: 8 of far_field's 24 views at 640x480 had ranges
ending short of their surface (one at 28 m against 45 m), and with this rule none did (docs/DECISIONS.md).
The far bound then reaches ``far_reach`` (2.5) times past the sparse point that sets it: with fewer photos
the sparse model holds hardly any of the far ground. far_field with 16 photos had 487 sparse points,
four of them beyond 20 m; every range ended at 24-30 m against a true 99th percentile of 38-42 m, and
the fused cloud held 55 % of the observable surface (fused F@0.2 % .709; with the reach .885). The
interval [1/far, 1/near] grows by 1-5 % on the zoo (12 % on aerial_grid, a nadir survey whose depths
span little; docs/DECISIONS.md).

``keep`` gives views their sources of an earlier run (photos added to a workspace): a view keeps
them while every one of them still qualifies as a source and its ``reselect_top`` best-scoring
sources now are among them, so that its final maps can be reused (:mod:`recon.mvs.reuse`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pycolmap
from scipy.spatial import cKDTree

from recon.geometry.transforms import project
from recon.mvs.ground_normal import up_direction
from recon.mvs.options import MVSOptions

log = logging.getLogger(__name__)

_ANGLE_PEAK = 5.0  # deg
_SIGMA_BELOW = 1.0
_SIGMA_ABOVE = 10.0
_OCCLUDER_RADIUS = 0.05  # of the image's longer side: how near in a source's image its own points are looked up
_OCCLUDER_DEPTH = 0.8  # a source's own point at under this share of a point's depth hides the point
_OCCLUDER_NEIGHBOURS = 3


@dataclass(frozen=True, eq=False)
class ViewCamera:
    """A pinhole camera of an image of the dense workspace: x_cam = R @ X + t, pixel ~ K @ x_cam."""

    name: str
    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int


@dataclass(frozen=True, eq=False)
class Problem:
    """One depth map to estimate: the reference image, its source images (best first), the depth range
    and the cameras of all of them (so a worker needs no sparse model); the ground's normal where the
    photos tell it (world frame, :mod:`recon.mvs.ground_normal`)."""

    ref: str
    sources: tuple[str, ...]
    depth_min: float
    depth_max: float
    cameras: dict[str, ViewCamera]
    ground: tuple[float, float, float] | None = None


def view_camera(image: pycolmap.Image, camera: pycolmap.Camera) -> ViewCamera:
    """The pinhole camera of a registered image with an undistorted (PINHOLE/SIMPLE_PINHOLE) camera."""
    if camera.model_name not in ("PINHOLE", "SIMPLE_PINHOLE"):
        raise ValueError(f"{image.name}: dense stereo needs undistorted pinhole cameras, got {camera.model_name}")
    return pinhole_view(image, camera)


def pinhole_view(image: pycolmap.Image, camera: pycolmap.Camera) -> ViewCamera:
    """The pinhole camera of a registered image: its camera's focal lengths and principal point (any
    distortion parameters left out)."""
    pose = image.cam_from_world()
    return ViewCamera(image.name, np.asarray(camera.calibration_matrix(), dtype=np.float64),
                      np.asarray(pose.rotation.matrix(), dtype=np.float64),
                      np.asarray(pose.translation, dtype=np.float64), int(camera.width), int(camera.height))


def model_views(model: Path) -> list[ViewCamera]:
    """Pinhole cameras of the registered images of an undistorted model folder, sorted by name."""
    rec = pycolmap.Reconstruction(str(model))
    views = [view_camera(img, rec.camera(img.camera_id)) for img in rec.images.values() if img.has_pose]
    return sorted(views, key=lambda v: v.name)


def scaled_to(view: ViewCamera, width: int, height: int) -> ViewCamera:
    """The camera of a view for an image of ``width`` x ``height`` (depth maps are computed smaller)."""
    sx, sy = width / view.width, height / view.height
    return replace(view, K=np.diag([sx, sy, 1.0]) @ view.K, width=width, height=height)


def _in_frame(cam: ViewCamera, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (N, 2) and depths (N,) of the points ``xyz`` (N, 3) in ``cam``, and whether each lies in
    front of it and projects inside its image."""
    uv, z = project(cam.K, cam.R, cam.t, xyz)
    with np.errstate(invalid="ignore"):
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    return uv, z, inside


def depths_in_view(cam: ViewCamera, xyz: np.ndarray) -> np.ndarray:
    """Depths of the points ``xyz`` (N, 3) in front of ``cam`` that project inside its image."""
    _, z, inside = _in_frame(cam, xyz)
    return z[inside]


def angle_weight(angle_deg: np.ndarray) -> np.ndarray:
    """Usefulness of a triangulation angle: 1 at 5 deg, falling fast below and slowly above."""
    sigma = np.where(angle_deg <= _ANGLE_PEAK, _SIGMA_BELOW, _SIGMA_ABOVE)
    return np.exp(-((angle_deg - _ANGLE_PEAK) ** 2) / (2 * sigma**2))


def observations(reconstruction: pycolmap.Reconstruction, ids: list[int]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sparse points (P, 3) and their observations by the images ``ids``: per observation, the point's
    row and the image's index in ``ids`` (int64 arrays)."""
    index = {image_id: i for i, image_id in enumerate(ids)}
    point_rows, image_cols, xyz = [], [], []
    for row, point in enumerate(reconstruction.points3D.values()):
        xyz.append(point.xyz)
        for element in point.track.elements:
            if element.image_id in index:
                point_rows.append(row)
                image_cols.append(index[element.image_id])
    return (np.asarray(xyz, dtype=np.float64).reshape(-1, 3), np.asarray(point_rows, dtype=np.int64),
            np.asarray(image_cols, dtype=np.int64))


def select_problems(reconstruction: pycolmap.Reconstruction, options: MVSOptions = MVSOptions(),
                    min_points: int = 10, keep: dict[str, tuple[str, ...]] | None = None,
                    reselect_top: int = 0) -> list[Problem]:
    """One problem per registered image of which some other image sees at least ``min_points``
    well-triangulated points; images without any such source are left out (logged). A view named in
    ``keep`` keeps those sources when all of them still qualify and include its ``reselect_top``
    best (module doc)."""
    cameras: dict[int, ViewCamera] = {}
    for image_id, image in reconstruction.images.items():
        if image.has_pose:
            cameras[image_id] = view_camera(image, reconstruction.cameras[image.camera_id])
    ids = sorted(cameras)
    up = up_direction([cameras[i].R for i in ids]) if options.ground_normal else None
    ground = None if up is None else (float(up[0]), float(up[1]), float(up[2]))
    xyz, obs_point, obs_image = observations(reconstruction, ids)
    centres = np.array([-cameras[i].R.T @ cameras[i].t for i in ids]).reshape(-1, 3)
    focals = np.array([np.sqrt(cameras[i].K[0, 0] * cameras[i].K[1, 1]) for i in ids])
    all_cameras = {cameras[i].name: cameras[i] for i in ids}
    observed = [np.unique(obs_point[obs_image == i]) for i in range(len(ids))]
    agreed = np.bincount(obs_point, minlength=len(xyz)) >= 3  # tracks of three photos or more (module doc)
    occluders = [_Occluders(cameras[image_id], xyz[observed[i]]) for i, image_id in enumerate(ids)]

    problems = []
    for i, image_id in enumerate(ids):
        cam = cameras[image_id]
        seen = observed[i]
        if len(seen) < min_points:
            log.info("%s: only %d sparse points, no depth map", cam.name, len(seen))
            continue
        pts, others, tracked = _seen_by_others(i, seen, xyz, obs_point, obs_image, observed, occluders)
        to_ref = xyz[pts] - centres[i]
        to_src = xyz[pts] - centres[others]
        cos = np.einsum("ij,ij->i", to_ref, to_src) / (
            np.linalg.norm(to_ref, axis=1) * np.linalg.norm(to_src, axis=1) + 1e-300)
        angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        useful = angle >= options.min_triangulation_angle
        depth_ref = xyz[pts] @ cam.R[2] + cam.t[2]
        depth_src = np.einsum("ij,ij->i", xyz[pts], np.array([cameras[ids[j]].R[2] for j in others]).reshape(-1, 3))
        depth_src += np.array([cameras[ids[j]].t[2] for j in others])
        footprint = (depth_ref / focals[i]) / np.maximum(depth_src / focals[others], 1e-300)
        scores = []
        for j in np.unique(others[useful]):
            mine = useful & (others == j)
            if mine.sum() < min_points:
                continue
            ratio = float(np.median(footprint[mine]))
            if not 1.0 / options.max_scale_ratio <= ratio <= options.max_scale_ratio:
                continue
            scores.append((float(angle_weight(angle[mine & tracked]).sum()), cameras[ids[j]].name))
        if not scores:
            log.info("%s: no source view with enough well-triangulated shared points", cam.name)
            continue
        scores.sort(key=lambda item: (-item[0], item[1]))
        sources = tuple(name for _, name in scores[: options.max_sources])
        kept = (keep or {}).get(cam.name)
        if kept and len(kept) <= options.max_sources and set(kept) <= {name for _, name in scores} \
                and set(sources[:reselect_top]) <= set(kept):
            sources = tuple(kept)
        z = xyz[seen] @ cam.R[2] + cam.t[2]
        z = z[z > 0]
        if len(z) < min_points:
            log.info("%s: too few points in front of the camera", cam.name)
            continue
        near = np.percentile(z, 1)
        in_view = depths_in_view(cam, xyz[agreed])
        far = np.max(in_view, initial=0.0 if len(in_view) >= min_points else np.percentile(z, 99))
        problems.append(Problem(
            ref=cam.name, sources=sources,
            depth_min=float(near / (1 + options.depth_margin) / options.near_reach),
            depth_max=float(far * (1 + options.depth_margin) * options.far_reach),
            cameras={name: all_cameras[name] for name in (cam.name, *sources)}, ground=ground))
    own_far = {problem.ref: problem.depth_max for problem in problems}  # each view reaches as far as its sources
    return [replace(problem, depth_max=max([problem.depth_max, *(own_far.get(s, 0.0) for s in problem.sources)]))
            for problem in problems]


class _Occluders:
    """A view's own sparse points in its image, to tell whether it sees another point (module doc)."""

    def __init__(self, cam: ViewCamera, points: np.ndarray):
        self.cam = cam
        uv, self.depth = project(cam.K, cam.R, cam.t, points)
        front = self.depth > 0
        uv, self.depth = uv[front], self.depth[front]
        self.tree = cKDTree(uv) if len(uv) else None
        self.radius = _OCCLUDER_RADIUS * max(cam.width, cam.height)

    def sees(self, points: np.ndarray) -> np.ndarray:
        """Whether each point lies in the view's frame, in front, and hidden by none of its own points."""
        uv, z, out = _in_frame(self.cam, points)
        if self.tree is None or not out.any():
            return out
        k = min(_OCCLUDER_NEIGHBOURS, len(self.depth))
        dist, nearest = self.tree.query(uv[out], k=k, distance_upper_bound=self.radius)
        dist, nearest = dist.reshape(len(dist), k), nearest.reshape(len(dist), k)
        found = np.isfinite(dist)
        near_depth = np.where(found, self.depth[np.minimum(nearest, len(self.depth) - 1)], np.inf)
        out[out] = ~np.any(near_depth < _OCCLUDER_DEPTH * z[out, None], axis=1)
        return out


def _seen_by_others(i: int, seen: np.ndarray, xyz: np.ndarray, obs_point: np.ndarray, obs_image: np.ndarray,
                    observed: list[np.ndarray], occluders: list[_Occluders]
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(point, view, tracked) triples: each point of ``seen`` (view ``i``'s) with each other view that
    sees it, by its track or by projection (module doc), and whether the track holds both; only views
    sharing a tracked point with ``i`` are tried."""
    candidates = np.unique(obs_image[np.isin(obs_point, seen)])
    pts, others, tracked = [], [], []
    for j in candidates[candidates != i]:
        track = np.isin(seen, observed[j])
        sees = track | occluders[j].sees(xyz[seen])
        pts.append(seen[sees])
        others.append(np.full(np.count_nonzero(sees), j))
        tracked.append(track[sees])
    if not pts:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
    return np.concatenate(pts), np.concatenate(others), np.concatenate(tracked)
