"""Measures of a stitched panorama against the synthetic environment it was rendered from."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np

from recon.panorama import Panorama
from recon.synth import panorama as sp

SEAM_SIDE = 9  # px: the seam jump compares 9-px-wide box means of the residual on either side of a seam


@dataclasses.dataclass(frozen=True)
class Columns:
    mapped: np.ndarray  # (N, 2) pixel coordinates of the marker directions by the estimated model
    found: np.ndarray  # (N, 2) marker centroids found in the panorama's pixels near them (NaN: none)
    mapped_error: np.ndarray  # (N,) mapped column - (azimuth * width / 360 + offset), px
    found_error: np.ndarray  # (N,) found column - the same truth, px
    content_error: np.ndarray  # (N,) |found - mapped|, px (both axes)


def world_to_panorama(pano: Panorama, rotations_gt: list[np.ndarray]) -> np.ndarray:
    """The rotation taking world directions to the panorama frame, through the first stitched
    photo: estimated camera-to-panorama times its true world-to-camera."""
    first = pano.registration.connected[0]
    return pano.model.rotations[0] @ rotations_gt[first]


def marker_columns(pano: Panorama, rotations_gt: list[np.ndarray], window: int = 12) -> Columns:
    """Each marker's direction is taken into the frame of the photo that sees it most centrally
    (true rotation) and mapped to the panorama with that photo's ESTIMATED rotation and the
    panorama's estimated projection; the marker is then looked for in the panorama's pixels."""
    model, connected = pano.model, pano.registration.connected
    az = sp.marker_azimuths()
    dirs = sp.direction(az)
    mapped = np.empty((len(az), 2))
    for n, d in enumerate(dirs):
        depth = [(rotations_gt[k] @ d)[2] for k in connected]
        c = int(np.argmax(depth))
        mapped[n] = model.to_pixel((rotations_gt[connected[c]] @ d)[None], camera=c)[0]
    found = np.array([marker_centroid(pano.image, x, y, window) for x, y in mapped])
    width = model.width
    truth = az * width / 360.0

    def against_truth(cols):
        diff = cols - truth
        offset = width / (2 * np.pi) * np.angle(np.mean(np.exp(2j * np.pi * diff / width)))
        return (diff - offset + width / 2) % width - width / 2

    return Columns(mapped, found, against_truth(mapped[:, 0]), against_truth(found[:, 0]),
                   np.abs(found - mapped).max(axis=1))


def marker_centroid(img: np.ndarray, x: float, y: float, window: int) -> tuple[float, float]:
    h, w = img.shape[:2]
    if not (np.isfinite(x) and np.isfinite(y)):
        return np.nan, np.nan
    cols = np.arange(int(x) - window, int(x) + window + 1) % w  # the panorama wraps
    rows = np.arange(max(0, int(y) - window), min(h, int(y) + window + 1))
    patch = img[rows][:, cols].astype(np.float32)
    weight = np.clip(np.minimum(patch[..., 0], patch[..., 2]) - patch[..., 1], 0, None)
    weight[~sp.marker_mask(img[rows][:, cols])] = 0
    if weight.sum() == 0:
        return np.nan, np.nan
    jj, ii = np.meshgrid(np.arange(len(cols)), np.arange(len(rows)))
    cx = (jj * weight).sum() / weight.sum() + int(x) - window + 0.5
    cy = (ii * weight).sum() / weight.sum() + rows[0] + 0.5
    return float(cx % w), float(cy)


def ground_truth(pano: Panorama, rotations_gt: list[np.ndarray]) -> np.ndarray:
    """The environment rendered straight into the panorama's geometry (float32 0-255, gain 1)."""
    model = pano.model
    h, w = model.height, model.width
    jj, ii = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dirs = model.to_direction(np.column_stack([jj.ravel(), ii.ravel()]))
    world = dirs @ world_to_panorama(pano, rotations_gt)  # = R^T d for each row d
    return (sp.environment_colour(world, 1.0 / model.scale) * 255.0).reshape(h, w, 3)


@dataclasses.dataclass(frozen=True)
class Seams:
    jump: float  # mean over seam pixels of |box mean of the residual left - right|, grey levels
    interior: float  # the same measure at pixels away from seams (the measure's own noise)
    wrap_jump: float  # the jump between the last column and the first (full circle), grey levels
    gain_spread: float  # max / min - 1 of each photo's mean brightness ratio panorama / truth
    seam_pixels: int


def seam_jumps(pano: Panorama, truth: np.ndarray) -> Seams:
    """Seam visibility: residual E = panorama - g x truth (g: per-channel least squares). Photo
    content and resampling differences average out in a box mean; an exposure or blending step
    does not. A seam pixel is where the photo label changes between horizontal neighbours."""
    img = pano.image.astype(np.float32)
    valid = pano.mask & (pano.labels >= 0)
    g = (img[valid] * truth[valid]).sum(0) / (truth[valid] ** 2).sum(0)
    resid = (img - g * truth) * valid[..., None]
    wrap = pano.model.full_circle
    pad = SEAM_SIDE
    border = cv2.BORDER_WRAP if wrap else cv2.BORDER_CONSTANT
    r = cv2.copyMakeBorder(resid, 0, 0, pad, pad, border)
    m = cv2.copyMakeBorder(valid.astype(np.float32), 0, 0, pad, pad, border)
    box = (SEAM_SIDE, SEAM_SIDE)
    mean = cv2.boxFilter(r, -1, box, normalize=False) / np.maximum(cv2.boxFilter(m, -1, box, normalize=False),
                                                                    1e-6)[..., None]
    full = cv2.boxFilter(m, -1, box, normalize=False) >= SEAM_SIDE * SEAM_SIDE  # the box is all covered
    half = SEAM_SIDE // 2
    w = img.shape[1]
    x = np.arange(w) + pad
    left, right = mean[:, x - half], mean[:, x + half + 1]  # boxes ending at x, starting at x + 1
    ok = full[:, x - half] & full[:, x + half + 1]
    step = np.abs(left - right).mean(axis=2)
    lab = pano.labels
    nxt = np.roll(lab, -1, axis=1) if wrap else np.concatenate([lab[:, 1:], lab[:, -1:]], axis=1)
    seam = (lab != nxt) & (lab >= 0) & (nxt >= 0) & ok
    near = cv2.dilate(seam.astype(np.uint8), np.ones((1, 4 * SEAM_SIDE), np.uint8)) > 0
    interior = ok & ~near & (lab >= 0)
    wrap_jump = float(step[:, -1][ok[:, -1]].mean()) if wrap else float("nan")
    ratios = []
    for k in range(len(pano.registration.connected)):
        sel = (lab == k) & valid
        if sel.sum() > 1000:
            ratios.append(img[sel].mean() / (g * truth[sel]).mean())
    return Seams(float(step[seam].mean()), float(step[interior].mean()), wrap_jump,
                 float(max(ratios) / min(ratios) - 1), int(seam.sum()))
