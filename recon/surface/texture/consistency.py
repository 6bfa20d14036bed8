"""Photo-consistency of the views of each face: a view that shows something else at a face than most
of its views do (a car parked in some of the photos, a passer-by, a reflection) is not used there.

After Waechter et al. 2014 ("Let There Be Color!", the photo-consistency check), who keep the views
whose mean colour of a face lies near the mode of all of them. Two changes:

- Colours are compared after dividing out each view's gain (per channel, the median over the faces it
  sees of its colour over their median colour): auto-exposure and white balance change every face of
  a photo alike and are not an inconsistency (the zoo's ``exposure_wb`` scene: +-0.7 stops, +-12 %).
- The mode and spread are the per-channel median and the median absolute deviation of the views'
  log colours (after the gains): robust to a minority of outliers, no iterations, vectorised over all faces at once.

A view is dropped for a face when its colour lies farther from the median than :data:`SPREAD` robust
standard deviations and at least :data:`FLOOR` (log units: 0.2 is a 22 % difference), and only where
:data:`MIN_VIEWS` views or more see the face and more than half of them are kept: with no clear
majority nothing is dropped, as nothing tells which view is right.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import cv2
import numpy as np

from recon.geometry.transforms import project
from recon.imaging.pixels import sample_bilinear

log = logging.getLogger(__name__)

MIN_VIEWS = 3
SPREAD = 3.0
FLOOR = 0.2
_BRIGHT = 20.0  # faces whose median colour has a channel below this (0-255) do not estimate the gains
_DARK = 8.0  # added to 0-255 colours before the log, so that noise in dark pixels does not count as colour


def face_colours(vertices: np.ndarray, faces: np.ndarray, face: np.ndarray, view: np.ndarray,
                 images: Sequence[np.ndarray], cameras: Sequence) -> np.ndarray:
    """The colour (E, 3; 0-255) of each face ``face[e]`` in view ``view[e]``: the photo, lightly blurred,
    at the face's centroid (faces of a mesh textured at photo resolution span a few pixels)."""
    centroid = np.asarray(vertices, np.float64)[np.asarray(faces)[face]].mean(axis=1)
    colours = np.zeros((len(face), 3), np.float32)
    for j, (image, cam) in enumerate(zip(images, cameras, strict=True)):
        at = np.flatnonzero(view == j)
        if len(at) == 0:
            continue
        uv, _ = project(cam.K, cam.R, cam.t, centroid[at])
        blurred = cv2.GaussianBlur(np.asarray(image, np.float32), (0, 0), 1.0)
        colours[at] = sample_bilinear(blurred, uv[:, 0], uv[:, 1])
    return colours


def inconsistent(face: np.ndarray, view: np.ndarray, colours: np.ndarray, n_faces: int, n_views: int) -> np.ndarray:
    """Which of the (face, view) entries, sorted by face, with ``colours`` (E, 3) show something other
    than most views of their face (module doc). The views' gains are estimated twice: the second time
    without the entries the first found inconsistent (a car over a third of a photo's faces would bias
    its gain)."""
    counts = np.bincount(face, minlength=n_faces)
    judged = counts[face] >= MIN_VIEWS
    colours = colours.astype(np.float64)
    out = np.zeros(len(face), bool)
    for _ in range(2):
        use = judged & ~out
        median = face_median(face, np.where(use[:, None], colours, np.nan), n_faces)
        use &= np.all(median[face] > _BRIGHT, axis=1)  # a gain is a ratio: not from dark colours
        gain = view_median(view[use], colours[use] / median[face[use]], n_views)
        corrected = np.log(colours / gain[view] + _DARK)
        distance = np.linalg.norm(corrected - face_median(face, corrected, n_faces)[face], axis=1)
        spread = 1.4826 * face_median(face, distance[:, None], n_faces)[:, 0]
        out = judged & (distance > np.maximum(SPREAD * spread, FLOOR)[face])
    kept = counts - np.bincount(face[out], minlength=n_faces)
    return out & (2 * kept[face] > counts[face])


def drop_inconsistent_views(quality: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                            images: Sequence[np.ndarray], cameras: Sequence) -> np.ndarray:
    """``quality`` (F, N: each view's quality for each face, 0 where unseen) with the inconsistent
    views of each face set to 0."""
    face, view = np.nonzero(quality > 0)  # sorted by face
    colours = face_colours(vertices, faces, face, view, images, cameras)
    out = inconsistent(face, view, colours, *quality.shape)
    quality = quality.copy()
    quality[face[out], view[out]] = 0.0
    log.info("photo-consistency: %d of %d face views dropped, on %d faces", int(out.sum()), len(face),
             len(np.unique(face[out])))
    return quality


def face_median(face: np.ndarray, values: np.ndarray, n_faces: int, chunk: int = 1 << 21) -> np.ndarray:
    """Per face the median of each column of ``values`` (E, C; NaN entries left out) over its entries,
    which are sorted by face; NaN where a face has none. Faces are taken in blocks, each as a dense
    (faces, most views, C) array sorted along its views (NaN and empty slots as +inf, at the end)."""
    out = np.full((n_faces, values.shape[1]), np.nan)
    starts = np.searchsorted(face, np.arange(n_faces + 1))
    width = max(int(np.diff(starts).max(initial=0)), 1)
    step = max(chunk // (width * values.shape[1]), 1)
    for first in range(0, n_faces, step):
        last = min(first + step, n_faces)
        lo, hi = starts[first], starts[last]
        slot = np.arange(lo, hi) - starts[face[lo:hi]]
        block = np.full((last - first, width, values.shape[1]), np.inf)
        block[face[lo:hi] - first, slot] = np.where(np.isnan(values[lo:hi]), np.inf, values[lo:hi])
        block.sort(axis=1)
        n = np.isfinite(block).sum(axis=1)  # (faces, C) entries that count
        below = np.take_along_axis(block, np.maximum(n - 1, 0)[:, None] // 2, axis=1)[:, 0]
        above = np.take_along_axis(block, (n // 2)[:, None], axis=1)[:, 0]
        out[first:last] = np.where(n > 0, 0.5 * (below + above), np.nan)
    return out


def view_median(view: np.ndarray, values: np.ndarray, n_views: int) -> np.ndarray:
    """Per view the median of each column of ``values`` (E, C) over its entries; 1 where it has none."""
    out = np.ones((n_views, values.shape[1]))
    order = np.argsort(view, kind="stable")
    bounds = np.searchsorted(view[order], np.arange(n_views + 1))
    for j in range(n_views):
        if bounds[j + 1] > bounds[j]:
            out[j] = np.median(values[order[bounds[j]:bounds[j + 1]]], axis=0)
    return out
