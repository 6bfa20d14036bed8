"""Which photos see each face, and how well (the data term of view selection).

Visibility is tested against the mesh's own depth map in each view (ray cast once per pixel): a view sees
a face when the face projects inside the photo (with a margin), faces the camera, and its centroid and
three corners (pulled 20% towards the centroid) land on pixels whose depth is theirs. A face within a
few pixels of a nearer surface (an occluding silhouette) keeps only a tenth of its quality in that view:
a geometry error of a pixel there would paint the occluder onto it.

The quality of a view is the projected area in pixels times its sharpness at the face: close, frontal and
sharp views score high. Waechter et al. (2014, "Let There Be Color!") take the gradient magnitude integral,
the area times the mean image gradient at the face; here the gradient (the mean at those four points) counts
relative to its median over the views that see the face, capped at 1. So a view blurred by motion or focus
still scores lower than the others, but no view scores higher because its photo shows more texture at the
face than the others do: where the mesh lies off the true surface, that is a view whose projection lands on
something else (say a textured table beside a dark object), and the plain integral chose it. On the zoo:
docs/DECISIONS.md.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np

from recon.geometry.transforms import camera_center, project
from recon.imaging.pixels import sample_bilinear

log = logging.getLogger(__name__)

_PULL = 0.2  # corners are pulled this far towards the centroid for the visibility test
_DEPTH_TOL = 0.01  # relative depth difference still counted as the same surface
_OCCLUDER_RADIUS = 2  # pixels: a nearer surface this close marks a face as next to a silhouette
_NEAR_SILHOUETTE = 0.1  # quality factor of a view in which the face lies next to a silhouette
_GRADIENT_FLOOR = 0.01  # so a view of a flat-coloured face still scores by its projected area


def gradient_magnitude(image: np.ndarray) -> np.ndarray:
    """Sobel gradient magnitude of the lightly blurred grey image, in [0, 1] intensity units per pixel."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32) / 255.0 if image.ndim == 3 \
        else image.astype(np.float32) / 255.0
    grey = cv2.GaussianBlur(grey, (0, 0), 1.0)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    return np.sqrt(gx * gx + gy * gy)


def _pixel(uv: np.ndarray, w: int, h: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of the pixel holding each point (pixel i spans [i, i + 1))."""
    x = np.clip(np.floor(np.nan_to_num(uv[:, 0])).astype(np.int64), 0, w - 1)
    y = np.clip(np.floor(np.nan_to_num(uv[:, 1])).astype(np.int64), 0, h - 1)
    return y, x


def view_quality(vertices: np.ndarray, faces: np.ndarray, images: Sequence[np.ndarray], cameras: Sequence,
                 depths: Sequence[np.ndarray], min_cosine: float = 0.1, border: int = 2) -> np.ndarray:
    """Quality (F, N) of each of N views for each face; 0 where the view does not see the face.
    ``depths``: the mesh's depth map in each view (camera z, inf where empty)."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    tri = vertices[faces]
    centroid = tri.mean(axis=1)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-30)
    targets = np.concatenate([centroid[:, None], (1 - _PULL) * tri + _PULL * centroid[:, None]], axis=1)
    kernel = np.ones((2 * _OCCLUDER_RADIUS + 1,) * 2, np.uint8)
    quality = np.zeros((len(faces), len(cameras)), np.float32)  # area, a tenth next to a silhouette
    sharpness = np.full((len(faces), len(cameras)), np.nan, np.float32)  # mean gradient + floor; NaN: unseen
    for j, (image, cam, depth) in enumerate(zip(images, cameras, depths, strict=True)):
        h, w = image.shape[:2]
        uv, z = project(cam.K, cam.R, cam.t, vertices)
        fuv = uv[faces]
        with np.errstate(invalid="ignore"):
            inside = np.all((fuv[..., 0] >= border) & (fuv[..., 0] <= w - border)
                            & (fuv[..., 1] >= border) & (fuv[..., 1] <= h - border), axis=1)
        inside &= np.all(z[faces] > 0, axis=1)
        to_cam = camera_center(cam.R, cam.t) - centroid
        cosine = np.einsum("ij,ij->i", normal, to_cam) / np.linalg.norm(to_cam, axis=1)
        cand = np.flatnonzero(inside & (cosine >= min_cosine))
        if len(cand) == 0:
            continue
        puv, pz = project(cam.K, cam.R, cam.t, targets[cand].reshape(-1, 3))
        y, x = _pixel(puv, w, h)
        seen = (np.abs(depth[y, x] - pz) <= _DEPTH_TOL * pz).reshape(-1, 4).all(axis=1)
        nearest = cv2.erode(np.where(np.isfinite(depth), depth, np.float32(3e38)).astype(np.float32), kernel)
        clear = (nearest[y, x] >= (1 - _DEPTH_TOL) * pz).reshape(-1, 4).all(axis=1)
        e1, e2 = fuv[cand, 1] - fuv[cand, 0], fuv[cand, 2] - fuv[cand, 0]
        area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        grad = sample_bilinear(gradient_magnitude(image), puv[:, 0], puv[:, 1]).reshape(-1, 4).mean(axis=1)
        quality[cand[seen], j] = (area * np.where(clear, 1.0, _NEAR_SILHOUETTE))[seen]
        sharpness[cand[seen], j] = grad[seen] + _GRADIENT_FLOOR
        log.debug("view %d sees %d faces, %d next to a silhouette", j, seen.sum(), (seen & ~clear).sum())
    quality *= relative_sharpness(sharpness)
    return quality


def relative_sharpness(sharpness: np.ndarray, block: int = 1 << 16) -> np.ndarray:
    """Each view's sharpness at each face (F, N; NaN where it does not see the face) over its median across
    the views that do, capped at 1 (module doc); 0 where unseen. Taken ``block`` faces at a time, so that
    the median's working copies stay small beside the (F, N) arrays."""
    out = np.zeros(sharpness.shape, np.float32)
    for first in range(0, len(sharpness), block):
        rows = sharpness[first:first + block]
        seen = np.isfinite(rows)
        median = np.nanmedian(np.where(seen.any(axis=1, keepdims=True), rows, 1.0), axis=1, keepdims=True)
        out[first:first + block] = np.where(seen, np.minimum(rows / median, 1.0), 0.0)
    return out


def unobstructed(points: np.ndarray, cam, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Whether each world point (N, 3) is what all four pixels of its bilinear footprint in the mesh's depth
    map (camera z, inf where empty) show: false at occlusions and within a pixel of a silhouette, where a
    photo's colour mixes in the occluder or background; and the points' pixels (N, 2), for sampling."""
    h, w = depth.shape
    uv, z = project(cam.K, cam.R, cam.t, points)
    ok = (z > 0) & np.all(np.isfinite(uv), axis=1)
    x0 = np.clip(np.floor(np.nan_to_num(uv[:, 0]) - 0.5).astype(np.int64), 0, w - 2)
    y0 = np.clip(np.floor(np.nan_to_num(uv[:, 1]) - 0.5).astype(np.int64), 0, h - 2)
    for dy in (0, 1):
        for dx in (0, 1):
            ok &= np.abs(depth[y0 + dy, x0 + dx] - z) <= 2 * _DEPTH_TOL * z
    return ok, uv
