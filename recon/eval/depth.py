"""A workspace's final depth maps against a synthetic scene's true surface, view by view.

It tells apart where a dense reconstruction loses quality: when the cameras are right (pose AUC)
and the depth maps are not, the stereo is at fault; when the depth maps are right and the fused
cloud is not, fusion is.

Each kept depth-map pixel is back-projected through its view's estimated camera, moved into the
ground truth's frame by the similarity that aligns the model's cameras with the true ones
(:func:`recon.eval.workspace.model_to_ground_truth`) and measured against the true mesh, in the
same thresholds as the surface metrics (fractions of the scene's extent):

- accuracy@tau: share of kept pixels within tau of the true surface;
- completeness@tau: share of the view's true-surface pixels (true depth > 0, resampled to the
  depth map's size; through the true lens where it has distortion, which the depth map's undistorted
  view has not) that hold a depth within tau of the surface;
- background: share of kept pixels where the truth has no surface (sky, black background): depths
  invented from nothing.

In a masked capture (the zoo's ``masked_object``) the view's surface is the masked object's pixels.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import cv2
import numpy as np

from recon.eval.groundtruth import Camera
from recon.eval.surface import THRESHOLDS, ground_truth_distance
from recon.geometry.transforms import Similarity, backproject
from recon.synth.dataset import SceneInfo


def depth_map_metrics(depth: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray, truth: np.ndarray,
                      to_gt: Similarity, scene: SceneInfo, thresholds=THRESHOLDS, stride: int = 1,
                      truth_camera: Camera | None = None) -> dict:
    """Figures (module doc; shares in [0, 1]) of one depth map with its camera (K at the map's size,
    pixel centres at +0.5, world-to-camera R, t in the model's frame) against the view's true depth
    map ``truth`` (any size; taken by ``truth_camera`` where that has lens distortion), over every
    ``stride``-th pixel of every ``stride``-th row."""
    height, width = depth.shape
    surface = _true_surface(truth, K, width, height, truth_camera)
    grid = np.zeros_like(surface)
    grid[::stride, ::stride] = True
    surface &= grid
    v, u = np.nonzero((depth > 0) & grid)
    points = to_gt.apply(backproject(K, R, t, np.column_stack([u + 0.5, v + 0.5]), depth[v, u]))
    distance = ground_truth_distance(scene)(points)
    out = {"kept": len(points) / np.count_nonzero(grid),
           "background": float(np.mean(~surface[v, u])) if len(points) else 0.0}
    for tau in thresholds:
        good = distance <= tau * scene.extent
        out[f"accuracy@{tau:g}"] = float(np.mean(good)) if len(points) else 0.0
        out[f"completeness@{tau:g}"] = float(np.count_nonzero(good & surface[v, u]) / max(surface.sum(), 1))
    return out


def _true_surface(truth: np.ndarray, K: np.ndarray, width: int, height: int, truth_camera: Camera | None) -> np.ndarray:
    """Bool mask (height, width) of the pixels of a pinhole depth map with intrinsics ``K`` whose true depth
    (``truth``) is > 0: ``truth`` resized, or, taken through a lens with distortion, looked up where the
    pixel's ray meets the true photo."""
    if truth_camera is None or not truth_camera.distorted:
        return cv2.resize(truth, (width, height), interpolation=cv2.INTER_NEAREST) > 0
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rays = backproject(K, np.eye(3), np.zeros(3), np.column_stack([u.ravel(), v.ravel()]), np.ones(u.size))
    at_origin = dataclasses.replace(truth_camera, R=np.eye(3), t=np.zeros(3))
    uv = np.floor(at_origin.project(rays)[0] * [truth.shape[1] / truth_camera.width,
                                                truth.shape[0] / truth_camera.height]).astype(np.int64)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < truth.shape[1]) & (uv[:, 1] >= 0) & (uv[:, 1] < truth.shape[0])
    surface = np.zeros(u.size, bool)
    surface[inside] = truth[uv[inside, 1], uv[inside, 0]] > 0
    return surface.reshape(height, width)


def workspace_depth_metrics(workspace: str | Path, scene: SceneInfo, thresholds=THRESHOLDS,
                            stride: int = 1) -> dict[str, dict]:
    """:func:`depth_map_metrics` of every final (geometric) depth map of a workspace, keyed by the view's
    ground-truth name; views without a depth map or a ground-truth camera are left out."""
    from recon.eval.workspace import model_to_ground_truth
    from recon.imaging.masks import load_mask
    from recon.mvs.colmap_io import read_depth_map
    from recon.mvs.views import model_views, scaled_to
    from recon.products import Published, SparseModel

    published = Published(workspace)
    to_gt = model_to_ground_truth(Path(workspace), scene.root)
    by_base = {Path(n).name: n for n in scene.image_names}
    true_cameras = scene.cameras()
    out = {}
    for view in model_views(published.dense / SparseModel.MODELS):
        path = published.depth_maps / f"{view.name}.geometric.bin"
        name = by_base.get(Path(view.name).name)
        if not path.exists() or name is None:
            continue
        depth = read_depth_map(path)
        cam = scaled_to(view, depth.shape[1], depth.shape[0])
        truth = scene.depth(name)
        if scene.masked:  # a masked capture's surface is its object: the rest is background to it
            truth = np.where(load_mask(scene.masks_dir, name, truth.shape), truth, 0)
        out[name] = depth_map_metrics(depth, cam.K, cam.R, cam.t, truth, to_gt, scene, thresholds, stride,
                                      true_cameras[name])
    return out
