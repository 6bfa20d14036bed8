"""Composition of registered photos into one panorama: warping (OpenCV's rotation warpers), exposure
compensation, seam finding (OpenCV's seam finders), blending (OpenCV's multi-band or feather
blenders), and the wrap of a full 360 deg panorama, which OpenCV does not handle.

The wrap. OpenCV warps a photo onto u = s atan2(x, z) with atan2 in (-pi, pi]: a photo that straddles
the back direction would be cut in two far-apart pieces, and its blenders and seam finders work on a
plane, where the last photo and the first one never meet. Here:

- each photo is warped in a frame turned about the panorama's vertical axis by a whole number of
  pixels (``n / s`` radians), so it lands around u = 0 and is then shifted back by ``n`` columns
  exactly: no photo is ever split, whatever its direction;
- a full circle is exactly ``W = 2 pi s`` columns (``s`` is chosen so that W is a whole number), and
  is composed on a strip ``W + M`` wide in which every photo near an end appears twice, W columns
  apart: the seam finder and the blender see the overlaps across the wrap like any other;
- the strip's columns [W, W + M) show the same directions as [0, M); the panorama's first M columns
  cross-fade from the former to the latter, so column W - 1 runs on into column 0 without a step.
"""

from __future__ import annotations

import dataclasses
import logging
import time

import cv2
import numpy as np

from recon.panorama.exposure import solve_gains
from recon.panorama.model import PanoramaModel
from recon.panorama.options import PanoramaOptions
from recon.panorama.register import PanoramaError, Registration

log = logging.getLogger(__name__)

COVERAGE_STEP = np.radians(0.1)  # azimuth sampling of the full-circle test and of the gap search
MAX_PLANE_RATIO = 8  # a plane panorama wider than this many photos is a projection mistake
# OpenCV's blenders hold pixels in 16-bit integers and truncate when they normalise by the weights:
# one photo alone through the 5-band blender came out 1.0 grey level darker on average (2.2 mean
# absolute error). Feeding values x16 (4 fractional bits; 255 x 16 x gain stays far below 32767)
# made that error 0.
FIXED_POINT = 16


@dataclasses.dataclass(frozen=True)
class Panorama:
    image: np.ndarray  # HxWx3 uint8 RGB
    mask: np.ndarray  # HxW bool: covered by some photo
    labels: np.ndarray  # HxW int16: which stitched photo the seams gave each pixel (-1: none)
    model: PanoramaModel
    registration: Registration
    gains: np.ndarray  # (n, 3) exposure gains applied to the stitched photos
    timings: dict[str, float]


@dataclasses.dataclass
class _Item:
    """One warped photo placed on the composition strip (a photo near the wrap gives two)."""

    owner: int  # index among the stitched photos
    x: int
    y: int
    image: np.ndarray  # uint8
    mask: np.ndarray  # bool


def compose(images: list[np.ndarray], reg: Registration, options: PanoramaOptions = PanoramaOptions()) -> Panorama:
    """Compose the registered photos (``images`` is the full input list, in input order)."""
    timings: dict[str, float] = {}
    t = time.perf_counter()
    photos = [images[k] for k in reg.connected]
    n = len(photos)
    s0 = float(np.median(reg.focals))
    proj = options.projection
    full, centres, scale = _geometry(photos, reg, options, s0)
    ratio = min(1.0, scale / s0)
    warper = cv2.PyRotationWarper(proj, scale)
    warped = []
    for k, img in enumerate(photos):
        h, w = img.shape[:2]
        if ratio < 1.0:
            img = cv2.resize(img, (max(1, round(w * ratio)), max(1, round(h * ratio))), interpolation=cv2.INTER_AREA)
        K = _intrinsics(reg.focals[k], reg.principal[k], img.shape[1] / w)
        shift = 0 if proj == "plane" else round(scale * centres[k])
        R = (_turn(-shift / scale) @ reg.rotations[k]).astype(np.float32)
        corner, out = warper.warp(img, K, R, cv2.INTER_LINEAR, cv2.BORDER_REFLECT)
        _, mask = warper.warp(np.full(img.shape[:2], 255, np.uint8), K, R, cv2.INTER_NEAREST, cv2.BORDER_CONSTANT)
        warped.append((corner[0] + shift, corner[1], out, mask > 0))
    u0 = warped[0][0] if full else min(u for u, _, _, _ in warped)
    v0 = min(v for _, v, _, _ in warped)
    height = max(v + m.shape[0] for _, v, _, m in warped) - v0
    if full:
        width = round(2 * np.pi * scale)
        margin = min(width // 4, max(32, 2 ** (options.blend_bands + 1)))
        items = _wrapped_items(warped, u0, v0, width, margin)
        strip = width + margin
    else:
        width = max(u + m.shape[1] for u, _, _, m in warped) - u0
        margin, strip = 0, width
        items = [_Item(k, u - u0, v - v0, img, m) for k, (u, v, img, m) in enumerate(warped)]
    timings["warp"] = time.perf_counter() - t
    log.info("warp: %d photos onto a %s %dx%d panorama (%.1f px/rad%s), %.2f s", n, proj, width, height, scale,
             ", full circle" if full else "", timings["warp"])

    t = time.perf_counter()
    seam_ratio = min(1.0, np.sqrt(options.seam_megapix * 1e6 / np.median([i.mask.size for i in items])))
    small = [_shrink(item, seam_ratio) for item in items]
    if options.exposure == "none":
        gains = np.ones((n, 3))
    else:
        gains = solve_gains([s[0] for s in small], [s[1] for s in small], [s[2] for s in small],
                            [i.owner for i in items], n, options.exposure == "channels",
                            round(width * seam_ratio) if full else None)
    timings["exposure"] = time.perf_counter() - t
    log.info("exposure: %s compensation, gains %.3f-%.3f, %.2f s", options.exposure, gains.min(), gains.max(),
             timings["exposure"])

    t = time.perf_counter()
    seams = _find_seams(small, [gains[i.owner] for i in items], options)
    timings["seams"] = time.perf_counter() - t
    log.info("seams: %s on %d warped photos at %.2f scale, %.2f s", options.seam, len(items), seam_ratio,
             timings["seams"])

    t = time.perf_counter()
    blender = _blender(options, strip, height)
    labels = np.full((height, strip), -1, np.int16)
    for item, seam in zip(items, seams):
        h, w = item.mask.shape
        seam = cv2.resize(cv2.dilate(seam, None), (w, h), interpolation=cv2.INTER_LINEAR_EXACT)
        keep = (seam > 0) & item.mask
        img = np.clip(item.image * gains[item.owner].astype(np.float32), 0, 255) * FIXED_POINT
        blender.feed(np.round(img).astype(np.int16), keep.astype(np.uint8) * 255, (item.x, item.y))
        labels[item.y:item.y + h, item.x:item.x + w][keep] = item.owner
    result, result_mask = blender.blend(None, None)
    pano = np.clip(np.round(result / FIXED_POINT), 0, 255).astype(np.uint8)
    covered = result_mask > 0
    timings["blend"] = time.perf_counter() - t
    log.info("blend: %s%s, %.2f s", options.blend,
             f" ({options.blend_bands} bands)" if options.blend == "multiband" else "", timings["blend"])

    if full:
        t = time.perf_counter()
        pano, covered, labels = _close_wrap(pano, covered, labels, width, margin)
        timings["wrap"] = time.perf_counter() - t
        log.info("wrap: columns %d-%d cross-faded into 0-%d, %.2f s", width, width + margin - 1, margin - 1,
                 timings["wrap"])
    model = PanoramaModel(proj, scale, width, height, int(u0), int(v0), full, reg.rotations, reg.focals,
                          reg.principal)
    return Panorama(pano, covered, labels, model, reg, gains, timings)


def _geometry(photos, reg: Registration, options: PanoramaOptions, s0: float) -> tuple[bool, np.ndarray, float]:
    """Whether the panorama is a full circle, each photo's centre azimuth (unwrapped so that the
    panorama is continuous), and the composition scale (pixels per radian)."""
    proj = options.projection
    warper = cv2.PyRotationWarper(proj, s0)
    sizes = [(p.shape[1], p.shape[0]) for p in photos]
    if proj == "plane":
        if options.full_circle:
            raise PanoramaError("panorama.full_circle: a plane projection cannot wrap; use spherical or cylindrical")
        rois = [warper.warpRoi(size, _intrinsics(f, c, 1.0), R.astype(np.float32))
                for size, f, c, R in zip(sizes, reg.focals, reg.principal, reg.rotations)]
        extent = max(x + w for x, _, w, _ in rois) - min(x for x, _, _, _ in rois)
        if extent > MAX_PLANE_RATIO * max(w for w, _ in sizes):
            raise PanoramaError(f"the photos span too wide a view for a plane projection ({extent} px); "
                                "use projection: spherical or cylindrical")
        return False, np.zeros(len(photos)), s0 * _limit(extent, options.max_width)
    centres = np.array([np.arctan2(R[0, 2], R[2, 2]) for R in reg.rotations])
    spans = []  # azimuth interval of each photo relative to its centre
    for size, f, c, R, centre in zip(sizes, reg.focals, reg.principal, reg.rotations, centres):
        x, _, w, _ = warper.warpRoi(size, _intrinsics(f, c, 1.0), (_turn(-centre) @ R).astype(np.float32))
        spans.append((x / s0, (x + w) / s0))
    spans = np.array(spans)
    grid = np.arange(0, 2 * np.pi, COVERAGE_STEP)
    rel = np.mod(grid[:, None] - (centres + spans[:, 0])[None, :], 2 * np.pi)
    covered = (rel <= (spans[:, 1] - spans[:, 0])[None, :]).any(axis=1)
    full = bool(covered.all()) if options.full_circle is None else options.full_circle
    if full:
        return True, centres, round(2 * np.pi * s0 * _limit(2 * np.pi * s0, options.max_width)) / (2 * np.pi)
    gaps = np.flatnonzero(~covered)
    if len(gaps):  # cut in the middle of the widest gap in the coverage (cyclic runs of uncovered samples)
        runs = np.split(gaps, np.flatnonzero(np.diff(gaps) > 1) + 1)
        if len(runs) > 1 and runs[0][0] == 0 and runs[-1][-1] == len(grid) - 1:
            runs = [np.concatenate([runs[-1], runs[0] + len(grid)]), *runs[1:-1]]
        widest = max(runs, key=len)
        cut = grid[0] + COVERAGE_STEP * (widest[0] + widest[-1]) / 2
    else:  # full coverage but told not to wrap: cut behind the first photo
        cut = centres[0] + np.pi
    centres = cut + np.mod(centres - cut, 2 * np.pi)
    extent = (max(centres + spans[:, 1]) - min(centres + spans[:, 0])) * s0
    return False, centres, s0 * _limit(extent, options.max_width)


def _limit(extent: float, max_width: int) -> float:
    return min(1.0, max_width / extent) if max_width else 1.0


def _intrinsics(focal: float, principal: np.ndarray, ratio: float) -> np.ndarray:
    """OpenCV K (pixel-index convention) of a photo resized by ``ratio``, from COLMAP-convention values."""
    return np.array([[focal * ratio, 0, principal[0] * ratio - 0.5], [0, focal * ratio, principal[1] * ratio - 0.5],
                     [0, 0, 1]], np.float32)


def _turn(angle: float) -> np.ndarray:
    """Rotation about the panorama's vertical (y) axis that adds ``angle`` to azimuths atan2(x, z)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _wrapped_items(warped, u0: int, v0: int, width: int, margin: int) -> list[_Item]:
    """Photos on the strip [0, width + margin): each at its column modulo ``width``, and again
    ``width`` to the left or right wherever that copy falls on the strip too (cropped to it)."""
    items = []
    for k, (u, v, img, mask) in enumerate(warped):
        x0 = (u - u0) % width
        w = mask.shape[1]
        for x in (x0 - width, x0, x0 + width):
            lo, hi = max(x, 0), min(x + w, width + margin)
            if lo < hi:
                items.append(_Item(k, lo, v - v0, img[:, lo - x:hi - x], mask[:, lo - x:hi - x]))
    return items


def _shrink(item: _Item, ratio: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """A seam-scale copy of an item: float32 image, bool mask, corner."""
    h, w = item.mask.shape
    size = (max(1, round(w * ratio)), max(1, round(h * ratio)))
    img = cv2.resize(item.image, size, interpolation=cv2.INTER_AREA).astype(np.float32)
    mask = cv2.resize(item.mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    return img, mask, (round(item.x * ratio), round(item.y * ratio))


def _find_seams(small: list, gains: list[np.ndarray], options: PanoramaOptions) -> list[np.ndarray]:
    """Seam masks (uint8, 255 = this photo) at seam scale, one per item."""
    masks = [(m.astype(np.uint8) * 255) for _, m, _ in small]
    if options.seam == "none":
        return masks
    finder = {"graphcut": lambda: cv2.detail_GraphCutSeamFinder("COST_COLOR_GRAD"),
              "dp": lambda: cv2.detail_DpSeamFinder("COLOR_GRAD"),
              "voronoi": lambda: cv2.detail.SeamFinder_createDefault(cv2.detail.SeamFinder_VORONOI_SEAM)}[options.seam]()
    imgs = [img * g.astype(np.float32) for (img, _, _), g in zip(small, gains)]
    found = finder.find(imgs, [c for _, _, c in small], masks)
    return [m.get() if isinstance(m, cv2.UMat) else np.asarray(m) for m in found]


def _blender(options: PanoramaOptions, width: int, height: int):
    if options.blend == "multiband":
        blender = cv2.detail_MultiBandBlender()
        blender.setNumBands(options.blend_bands)
    elif options.blend == "feather":
        blender = cv2.detail_FeatherBlender()
        blender.setSharpness(1.0 / max(1.0, 0.05 * np.sqrt(width * height)))  # OpenCV stitcher's default
    else:
        blender = cv2.detail.Blender_createDefault(cv2.detail.Blender_NO)
    blender.prepare((0, 0, width, height))
    return blender


def _close_wrap(pano: np.ndarray, covered: np.ndarray, labels: np.ndarray, width: int, margin: int):
    """The ``width`` columns of the panorama from the ``width + margin`` strip: its first ``margin``
    columns fade from the strip's copy past the end (weight 1 at column 0, continuing column
    width - 1) to its own (weight 1 at column margin - 1, continuing column margin)."""
    alpha = ((np.arange(margin) + 0.5) / margin)[None, :]
    right, left = pano[:, width:].astype(np.float32), pano[:, :margin].astype(np.float32)
    w_right = (1 - alpha) * covered[:, width:]
    w_left = alpha * covered[:, :margin]
    total = w_right + w_left
    mixed = (right * w_right[..., None] + left * w_left[..., None]) / np.maximum(total, 1e-6)[..., None]
    out = pano[:, :width].copy()
    out[:, :margin] = np.clip(np.round(mixed), 0, 255).astype(np.uint8)
    cov = covered[:, :width].copy()
    cov[:, :margin] = total > 0
    lab = labels[:, :width].copy()
    lab[:, :margin] = np.where(w_right > w_left, labels[:, width:], labels[:, :margin])
    return out, cov, lab
