"""Baking the atlas: photo pixels into charts, colour corrections on top, fill blocks for unseen faces.

Photo colours are copied into the atlas, and mixed in from other photos, with Lanczos interpolation
(OpenCV's 8 x 8 kernel, :func:`recon.imaging.pixels.sample_lanczos`): bilinear lookups between pixel
centres blur what the atlas stores, and a viewer's bilinear lookup in the atlas blurs it again. Rendered
back into its own photo at 1.5 texels per pixel, a texture gives the photo back at 43.5 dB against 37.7
with bilinear lookups (tests/surface/test_texture.py); the zoo's held-out views: docs/DECISIONS.md.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.linalg import spsolve

from recon.geometry.transforms import project
from recon.imaging.pixels import sample_bilinear, sample_lanczos
from recon.surface.texture.atlas import FILL_BLOCK, Layout
from recon.surface.texture.raster import rasterize
from recon.surface.texture.views import unobstructed

log = logging.getLogger(__name__)

_DEPTH_STEP = 0.01  # relative depth change per texel still taken for the same surface continuing
_MIX_BLOCK = 1 << 22  # texels mixed at once (about 0.5 GB of working arrays)


def vertex_colors(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, corner_corr: np.ndarray,
                  images: Sequence[np.ndarray], cameras: Sequence) -> np.ndarray:
    """Colour (V, 3; float 0-255) of each vertex: the mean over its textured faces of that face's photo at
    the vertex plus the face's correction there; vertices of no textured face are interpolated
    harmonically over the mesh edges (grey where a piece has no textured face at all)."""
    n = len(vertices)
    acc = np.zeros((n, 3))
    cnt = np.zeros(n)
    for j in np.unique(labels[labels >= 0]):
        sel = np.flatnonzero(labels == j)
        v = faces[sel].ravel()
        cam = cameras[j]
        uv, _ = project(cam.K, cam.R, cam.t, vertices[v])
        col = sample_bilinear(images[j], uv[:, 0], uv[:, 1]) + corner_corr[sel].reshape(-1, 3)
        np.add.at(acc, v, col)
        np.add.at(cnt, v, 1)
    known = cnt > 0
    color = np.full((n, 3), 128.0)
    color[known] = acc[known] / cnt[known, None]
    unknown = np.flatnonzero(~known & np.isin(np.arange(n), faces))
    if len(unknown):
        e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
        adj = ((adj + adj.T) > 0).astype(np.float64)
        lap = sp.diags(np.asarray(adj.sum(1)).ravel()) - adj
        luu = lap[unknown][:, unknown] + 1e-6 * sp.identity(len(unknown))
        rhs = -lap[unknown][:, np.flatnonzero(known)] @ color[known] + 1e-6 * 128.0
        color[unknown] = np.asarray(spsolve(luu.tocsc(), rhs)).reshape(-1, 3)
    return np.clip(color, 0, 255)


def _chart_pixels(image: np.ndarray, chart, scale: float, gutter: int, nearest: bool = False) -> np.ndarray:
    """The chart's texels: photo pixels under the affine map texel = (photo - origin) * scale + gutter,
    Lanczos-interpolated (module doc), or the nearest pixel's (depths)."""
    m = np.array([[scale, 0, gutter - chart.origin[0] * scale + 0.5 * scale - 0.5],
                  [0, scale, gutter - chart.origin[1] * scale + 0.5 * scale - 0.5]])
    return cv2.warpAffine(image, m, (chart.w, chart.h), flags=cv2.INTER_NEAREST if nearest else cv2.INTER_LANCZOS4,
                          borderMode=cv2.BORDER_REPLICATE)


@dataclass(frozen=True)
class Mixing:
    """What :func:`bake` needs to average each texel over the photos that see its face nearly as well as
    the chosen one: the mesh's vertices, each view's quality at each face (F, views), the views' cameras,
    and the least share of the chosen view's quality a view must have to be mixed in."""

    vertices: np.ndarray
    quality: np.ndarray
    cameras: Sequence
    min_ratio: float


def _mix_views(atlas: np.ndarray, face_map: np.ndarray, bary: np.ndarray, faces: np.ndarray, labels: np.ndarray,
               mixing: Mixing, photo: Callable[[int], np.ndarray], depths: Sequence[np.ndarray]) -> None:
    """Each texel on a face becomes the quality-weighted mean of its chosen photo and the other photos
    that see its point unobstructed with at least ``mixing.min_ratio`` of the chosen view's quality (in
    place). Texels are taken in blocks of :data:`_MIX_BLOCK`, so that memory stays bounded on a full
    atlas."""
    vertices, quality, cameras, min_ratio = mixing.vertices, mixing.quality, mixing.cameras, mixing.min_ratio
    flat = atlas.reshape(-1, 3)
    all_covered = np.flatnonzero(face_map.ravel() >= 0)
    for first in range(0, len(all_covered), _MIX_BLOCK):
        covered = all_covered[first:first + _MIX_BLOCK]
        face = face_map.ravel()[covered]
        chosen = np.maximum(quality[face, labels[face]].astype(np.float64), 1e-12)
        points = np.einsum("nk,nkc->nc", bary.reshape(-1, 3)[covered], vertices[faces[face]])
        total = flat[covered] * chosen[:, None]
        weight = chosen.copy()
        for j in range(quality.shape[1]):
            q = quality[face, j]
            at = np.flatnonzero((q >= min_ratio * chosen) & (q > 0) & (labels[face] != j))
            if len(at) == 0:
                continue
            cam = cameras[j]
            clear, uv = unobstructed(points[at], cam, depths[j])
            at, uv = at[clear], uv[clear]
            total[at] += sample_lanczos(photo(j), uv[:, 0], uv[:, 1]) * q[at, None]
            weight[at] += q[at]
        flat[covered] = total / weight[:, None]


def bake(lay: Layout, faces: np.ndarray, labels: np.ndarray, corner_corr: np.ndarray,
         vertex_color: np.ndarray, images: Sequence[np.ndarray], depths: Sequence[np.ndarray],
         mixing: Mixing | None = None) -> np.ndarray:
    """The atlas (H, W, 3; float 0-255); ``depths`` are the mesh's depth maps in the views.

    Texels whose centre lies on a face get the photo's colour plus the barycentric interpolation of the
    face's corner corrections; with ``mixing``, the photo's colour is first averaged with the other
    views' (:func:`_mix_views`). The other texels of a chart (its gutter) keep the photo where it shows
    the surface continuing (depth close to that of the nearest covered texel), so a lookup on a seam sees
    the photo's colour there; where the photo shows something else beyond the patch (an occluder, the
    background: patches often end where their photo stops seeing the surface) they copy the nearest
    covered texel. Either way they take the nearest covered texel's correction."""
    atlas = np.zeros((lay.height, lay.width, 3), np.float32)
    depth = np.full((lay.height, lay.width), np.inf, np.float32)
    sources = {}

    def photo(j: int) -> np.ndarray:
        if j not in sources:
            img = np.asarray(images[j], np.float32)
            if lay.scale < 1:  # anti-alias before shrinking
                img = cv2.GaussianBlur(img, (0, 0), 0.5 * np.sqrt(1 / lay.scale**2 - 1) + 1e-3)
            sources[j] = img
        return sources[j]

    for chart in lay.charts:
        rect = np.s_[chart.y:chart.y + chart.h, chart.x:chart.x + chart.w]
        atlas[rect] = _chart_pixels(photo(chart.view), chart, lay.scale, lay.gutter)
        depth[rect] = _chart_pixels(np.asarray(depths[chart.view], np.float32), chart, lay.scale, lay.gutter, True)
    seen = np.flatnonzero(labels >= 0)
    face_map, bary = rasterize(lay.corner_xy[seen], seen, lay.height, lay.width)
    if mixing is not None:
        _mix_views(atlas, face_map, bary, faces, labels, mixing, photo, depths)
    covered = face_map >= 0
    corr = np.zeros_like(atlas)
    corr[covered] = np.einsum("nk,nkc->nc", bary[covered], corner_corr[face_map[covered]])
    dist, (iy, ix) = ndimage.distance_transform_edt(~covered, return_indices=True)
    with np.errstate(invalid="ignore"):  # inf - inf off the surface: not a continuation
        continues = np.abs(depth - depth[iy, ix]) <= _DEPTH_STEP * (1 + dist) * depth[iy, ix]
    atlas = np.where(continues[..., None], atlas, atlas[iy, ix]) + corr[iy, ix]
    if len(lay.fill_faces):
        c = vertex_color[faces[lay.fill_faces]]  # U, 3 corners, 3
        block = np.empty((len(c), FILL_BLOCK, FILL_BLOCK, 3), np.float32)
        inner = np.stack([np.stack([c[:, 0], c[:, 1]], 1), np.stack([c[:, 2], c[:, 1] + c[:, 2] - c[:, 0]], 1)], 1)
        block[:] = np.pad(inner, ((0, 0), (1, 1), (1, 1), (0, 0)), mode="edge")
        yy = lay.fill_xy[:, 1, None, None] + np.arange(FILL_BLOCK)[None, :, None]
        xx = lay.fill_xy[:, 0, None, None] + np.arange(FILL_BLOCK)[None, None, :]
        atlas[yy, xx] = block
    return np.clip(atlas, 0, 255)
