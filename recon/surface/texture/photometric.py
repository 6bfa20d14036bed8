"""Photometric calibration of the photos before texturing: each photo's gain (exposure and white
balance) and its camera's vignetting, from the colours the photos show of the same faces.

Model, in the photos' own (gamma-encoded) values: face f seen by view v at normalised radius r
(distance from the principal point over the half diagonal) shows ``c = A_f * g_v * V(r)``, with A_f
the face's colour, g_v the view's per-channel gain and ``V(r) = 1 + a r^2 + b r^4`` shared by the
photos of one size (one camera). A power-law tone curve keeps both a gain and a fall-off in linear
light multiplicative in these values. Estimated by alternating medians (robust to the few views that
show something else at a face) and a least-squares fit of V to the median ratios in bins of r^2, in a
few rounds. The gains are normalised to a median of 1 over the views, per channel: the typical
photo's exposure and white balance are kept, the differences between photos go.

Without it, the texture of each chart keeps the exposure of the photo it came from and darkens towards
that photo's corners; global seam levelling (:mod:`.levelling`) was the remedy, but it also shifts
charts whose seams lie on creases (docs/DECISIONS.md).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recon.geometry.transforms import project
from recon.surface.texture.consistency import face_colours, face_median, view_median

log = logging.getLogger(__name__)

MIN_VIEWS = 3  # faces seen by fewer views do not inform the calibration
_DARK, _BRIGHT = 20.0, 235.0  # faces with a channel outside these (0-255) neither: ratios of dark or clipped colours
_ROUNDS = 4
_BINS = 16
_MIN_PER_BIN = 50
#: a fitted fall-off outside these anywhere out to the corners is no lens's, and no vignetting is corrected: a
#: lens darkens its corners, and not to under a quarter of its centre. Where the faces fill only the middle of the photos
#: (an object on a turntable), the fit, extrapolated to the corners, made them 2.8 times brighter than the
#: centre. The fall-off applied is never below the lowest value (past the corners of an off-centre principal
#: point).
_LOWEST, _BRIGHTEST = 0.25, 1.1
#: a view whose gain in some channel comes out beyond this factor (3 stops) from the median keeps gain 1:
#: a photo that shows mostly something else at the faces it is matched to (poses off, a black background
#: where the mesh has the object) gave a gain of 0.00, and the photo divided by it came out white or NaN
MAX_GAIN = 8.0


@dataclass(frozen=True)
class Calibration:
    """Per view its gain (N, 3), per view its group (photos of one size), per group (a, b) of V."""

    gain: np.ndarray
    group: np.ndarray
    falloff: np.ndarray

    def vignetting(self, j: int, r2: np.ndarray) -> np.ndarray:
        return np.maximum(_falloff(*self.falloff[self.group[j]], r2), _LOWEST)

    def apply(self, j: int, photo: np.ndarray, cam) -> np.ndarray:
        """Photo ``j`` (H, W, 3; 0-255) as it would look at the median gain and without vignetting."""
        h, w = photo.shape[:2]
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        r2 = _radius2(xx + 0.5, yy + 0.5, np.asarray(cam.K), w, h)
        factor = self.vignetting(j, r2)[..., None] * self.gain[j].astype(np.float32)
        return np.clip(np.asarray(photo, np.float32) / factor, 0.0, 255.0)


def _radius2(x, y, K: np.ndarray, width: int, height: int):
    """Squared distance from the principal point over the squared half diagonal."""
    return ((x - K[0, 2]) ** 2 + (y - K[1, 2]) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)


def calibrate(face: np.ndarray, view: np.ndarray, colours: np.ndarray, radius2: np.ndarray, group: np.ndarray,
              n_faces: int) -> Calibration:
    """The calibration from (face, view) entries sorted by face, their colours (E, 3; 0-255) and
    squared normalised radii (E,); ``group`` gives each view's group (module doc)."""
    n_views, n_groups = len(group), int(group.max()) + 1
    colours = np.asarray(colours, np.float64)
    median = face_median(face, colours, n_faces)
    counts = np.bincount(face, minlength=n_faces)
    usable = (counts[face] >= MIN_VIEWS) & np.all((median[face] > _DARK) & (median[face] < _BRIGHT), axis=1)
    f, v, c, r2 = face[usable], view[usable], colours[usable], radius2[usable]
    gain, falloff = np.ones((n_views, 3)), np.zeros((n_groups, 2))
    if len(f) == 0:
        return Calibration(gain, group, falloff)
    for _ in range(_ROUNDS):
        a, b = falloff[group[v]].T
        vig = np.maximum(_falloff(a, b, r2), _LOWEST)[:, None]
        albedo = face_median(f, c / (gain[v] * vig), n_faces)
        gain = view_median(v, c / (albedo[f] * vig), n_views)
        gain /= np.median(gain, axis=0)
        implausible = np.any((gain > MAX_GAIN) | (gain < 1.0 / MAX_GAIN), axis=1)
        gain[implausible] = 1.0
        ratio = (c / (albedo[f] * gain[v])).mean(axis=1)
        falloff = np.array([_fit_falloff(r2[group[v] == k], ratio[group[v] == k]) for k in range(n_groups)])
    log.info("photometric calibration: gains %.2f-%.2f, vignetting at the corners %s", gain.min(), gain.max(),
             ", ".join(f"{_falloff(a, b, 1.0):.2f}" for a, b in falloff))
    if implausible.any():
        log.warning("photometric calibration: %d photo(s) left uncorrected: the colours they show of the mesh's faces "
                    "differ from the other photos' by more than %g times (poses off, or something else in view)",
                    int(implausible.sum()), MAX_GAIN)
    return Calibration(gain, group, falloff)


def _fit_falloff(r2: np.ndarray, ratio: np.ndarray) -> tuple[float, float]:
    """(a, b) of ``ratio ~ s (1 + a r2 + b r2^2)`` fitted to the median ratio in bins of r2."""
    if len(r2) == 0:
        return 0.0, 0.0
    edges = np.linspace(0.0, max(float(r2.max()), 1e-6), _BINS + 1)
    which = np.clip(np.digitize(r2, edges) - 1, 0, _BINS - 1)
    rows, values, weights = [], [], []
    for k in range(_BINS):
        inside = which == k
        if inside.sum() >= _MIN_PER_BIN:
            x = float(np.median(r2[inside]))
            rows.append([1.0, x, x * x])
            values.append(float(np.median(ratio[inside])))
            weights.append(np.sqrt(inside.sum()))
    if len(rows) < 4:
        return 0.0, 0.0
    w = np.asarray(weights)[:, None]
    (s, a, b), *_ = np.linalg.lstsq(np.asarray(rows) * w, np.asarray(values) * w[:, 0], rcond=None)
    if s <= 0:
        return 0.0, 0.0
    a, b = a / s, b / s
    out_to_corners = _falloff(a, b, np.linspace(0.0, 1.0, 21))
    if out_to_corners.max() > _BRIGHTEST or out_to_corners.min() < _LOWEST:
        return 0.0, 0.0
    return a, b


def _falloff(a, b, r2):
    """V(r) = 1 + a r^2 + b r^4 at squared normalised radii ``r2`` (module doc)."""
    return 1.0 + a * r2 + b * r2 * r2


def calibrate_photos(quality: np.ndarray, vertices: np.ndarray, faces: np.ndarray, images: Sequence[np.ndarray],
                     cameras: Sequence) -> Calibration:
    """The calibration of the photos from the faces each sees (``quality`` > 0: F, N)."""
    face, view = np.nonzero(quality > 0)  # sorted by face
    colours = face_colours(vertices, faces, face, view, images, cameras)
    centroid = np.asarray(vertices, np.float64)[np.asarray(faces)[face]].mean(axis=1)
    radius2 = np.zeros(len(face))
    sizes: dict[tuple[int, int], int] = {}
    group = np.zeros(len(images), np.int64)
    for j, (image, cam) in enumerate(zip(images, cameras, strict=True)):
        h, w = image.shape[:2]
        group[j] = sizes.setdefault((w, h), len(sizes))
        at = np.flatnonzero(view == j)
        uv, _ = project(cam.K, cam.R, cam.t, centroid[at])
        radius2[at] = _radius2(uv[:, 0], uv[:, 1], np.asarray(cam.K), w, h)
    return calibrate(face, view, colours, radius2, group, quality.shape[0])
