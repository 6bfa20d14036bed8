"""The texture atlas layout: each patch's projection into its photo is its chart.

A chart is the patch's bounding box in its photo (grown by a gutter), scaled by one global factor, so
with scale 1 its texels are the photo's pixels, copied unresampled. Faces no photo sees get a 4 x 4 texel
block each, whose centre 2 x 2 texels hold the three corner colours (and the fourth that makes bilinear
lookups inside the face exactly linear). Charts are packed on shelves (tallest first); when the atlas
would exceed the largest allowed side, the scale shrinks until it fits.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recon.geometry.transforms import project

log = logging.getLogger(__name__)

FILL_BLOCK = 4  # texels per side of an unseen face's block
FILL_CORNERS = np.array([[1.5, 1.5], [2.5, 1.5], [1.5, 2.5]])  # its corners' texel coordinates in the block


@dataclass(frozen=True)
class Chart:
    """A patch's rectangle: texels [x, x + w) x [y, y + h) of the atlas show photo ``view`` with texel
    coordinate = (photo coordinate - origin) * scale + gutter + (x, y)."""

    view: int
    origin: tuple[int, int]
    x: int
    y: int
    w: int
    h: int


@dataclass(frozen=True)
class Layout:
    """Where every face corner lies in the atlas (texel coordinates, centres at +0.5)."""

    width: int
    height: int
    scale: float
    gutter: int
    charts: list[Chart]
    corner_xy: np.ndarray  # (F, 3, 2)
    fill_faces: np.ndarray  # (U,) faces seen by no photo
    fill_xy: np.ndarray  # (U, 2) their blocks' top-left texels


def pack(sizes: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Shelf packing of rectangles (N, 2: w, h): their top-left corners (N, 2) and the atlas width, height
    (multiples of 4)."""
    if len(sizes) == 0:
        return np.zeros((0, 2), np.int64), 4, 4
    area = float((sizes[:, 0] * sizes[:, 1]).sum())
    width = int(max(sizes[:, 0].max(), np.ceil(np.sqrt(area * 1.08))))
    width += -width % 4
    order = np.lexsort((-sizes[:, 0], -sizes[:, 1]))
    pos = np.zeros((len(sizes), 2), np.int64)
    x = y = shelf = 0
    for i in order:
        w, h = sizes[i]
        if x + w > width:
            x, y, shelf = 0, y + shelf, 0
        pos[i] = (x, y)
        x += w
        shelf = max(shelf, h)
    height = y + shelf
    return pos, width, height + (-height % 4)


def layout(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, patch: np.ndarray,
           cameras: Sequence, max_size: int, texel_scale: float = 1.0, gutter: int = 3) -> Layout:
    """Charts for the patches (faces with ``labels`` >= 0 grouped by ``patch``) and blocks for unseen faces,
    packed into an atlas no larger than ``max_size`` per side."""
    faces = np.asarray(faces, np.int64)
    seen = np.flatnonzero(labels >= 0)
    fill_faces = np.flatnonzero(labels < 0)
    order = seen[np.argsort(patch[seen], kind="stable")]
    ids, starts = np.unique(patch[order], return_index=True)
    groups = np.split(order, starts[1:]) if len(ids) else []
    views = [int(labels[g[0]]) for g in groups]
    proj = np.zeros((len(faces), 3, 2))
    for j in set(views):
        sel = seen[labels[seen] == j]
        cam = cameras[j]
        uv, _ = project(cam.K, cam.R, cam.t, vertices[faces[sel]].reshape(-1, 3))
        proj[sel] = uv.reshape(-1, 3, 2)
    lo = np.array([proj[g].reshape(-1, 2).min(0) for g in groups]).reshape(-1, 2)
    hi = np.array([proj[g].reshape(-1, 2).max(0) for g in groups]).reshape(-1, 2)
    origin = np.floor(lo).astype(np.int64)
    fill_sizes = np.full((len(fill_faces), 2), FILL_BLOCK)
    scale = texel_scale
    for _ in range(30):
        sizes = np.ceil((hi - origin) * scale).astype(np.int64) + 2 * gutter
        pos, width, height = pack(np.concatenate([sizes, fill_sizes]))
        if max(width, height) <= max_size:
            break
        scale *= 0.97 * min(1.0, max_size / max(width, height)) ** 0.5
    else:
        raise ValueError(f"the texture does not fit into {max_size} x {max_size} texels")
    corner_xy = np.zeros((len(faces), 3, 2))
    charts = []
    for k, g in enumerate(groups):
        corner_xy[g] = (proj[g] - origin[k]) * scale + gutter + pos[k]
        charts.append(Chart(views[k], (int(origin[k, 0]), int(origin[k, 1])), int(pos[k, 0]), int(pos[k, 1]),
                            int(sizes[k, 0]), int(sizes[k, 1])))
    fill_xy = pos[len(groups):]
    corner_xy[fill_faces] = fill_xy[:, None, :] + FILL_CORNERS[None]
    log.info("atlas %d x %d: %d charts, %d unseen faces, scale %.3f", width, height, len(charts),
             len(fill_faces), scale)
    return Layout(width, height, scale, gutter, charts, corner_xy, fill_faces, fill_xy)
