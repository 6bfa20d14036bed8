"""Exposure brackets: grouping the shots of one view, and merging them into one well-exposed image.

Merging methods:

- ``mertens`` (exposure fusion; Mertens, Kautz & Van Reeth 2007): a per-pixel weighted blend of the
  brackets in a Laplacian pyramid, weights favouring contrast, saturation and mid-tones. Needs no
  exposure times and no camera response; the usual choice for feature matching.
- ``debevec``: recovers the camera response curve and the scene radiance from the exposure times
  (Debevec & Malik 1997), then tone-maps it back to 8 bits for feature matching: log luminance,
  stretched between its 0.5th and 99.5th percentiles, then CLAHE for local contrast, with the
  radiance's colour ratios put back. Global operators (Reinhard, Drago) squeeze 8+ stops into 8
  bits and lose the local contrast that SIFT needs: on the synthetic 8-stop scene of the tests
  they gave fewer features than the best single exposure. uint8 input only.

Hand-held brackets are first aligned by whole-pixel translation with median threshold bitmaps
(Ward 2003), which compare exposures without knowing the camera response. (Refining the shift to
sub-pixel with ECC was tried and made it worse across exposures: +-0.5 px errors on still shots.)
"""

from __future__ import annotations

import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from PIL import Image

from recon.imaging.contrast import ClaheOptions, clahe
from recon.imaging.pixels import check_image, from_float, max_value, to_gray

logger = logging.getLogger(__name__)

_EXIF_IFD = 0x8769
_EXPOSURE_TIME = 0x829A


def _bgr(image: np.ndarray) -> np.ndarray:
    return image[..., ::-1] if image.ndim == 3 else image


def _align(images: list[np.ndarray]) -> list[np.ndarray]:
    """Translate every image onto the middle exposure by whole pixels (MTB on 8-bit gray versions).

    Shifts are measured between neighbours in brightness order and chained, since exposures
    several stops apart share little (one clipped where the other is dark).
    """
    mtb = cv2.createAlignMTB()
    gray8 = [to_gray(im) if im.dtype == np.uint8 else
             np.rint(to_gray(im) / 257.0).astype(np.uint8) for im in images]
    order = sorted(range(len(images)), key=lambda k: float(gray8[k].mean()))
    offsets = {order[0]: np.zeros(2, int)}
    for prev, cur in zip(order, order[1:]):
        offsets[cur] = offsets[prev] + np.array(mtb.calculateShift(gray8[prev], gray8[cur]))
    ref = offsets[order[len(order) // 2]]
    out = []
    for k, im in enumerate(images):
        shift = offsets[k] - ref
        if np.any(shift):
            logger.debug("bracket image %d shifted by %s px", k, tuple(int(v) for v in shift))
            im = mtb.shiftMat(im, tuple(int(v) for v in shift))
        out.append(im)
    return out


def merge_brackets(images: Sequence[np.ndarray], exposure_times: Sequence[float] | None = None,
                   method: Literal["mertens", "debevec"] = "mertens", align: bool = True) -> np.ndarray:
    """Merge differently exposed images of one view into one image of the same dtype and channels.

    ``exposure_times`` (seconds) are required by ``debevec`` and ignored by ``mertens``.
    """
    images = list(images)
    if len(images) < 2:
        raise ValueError("a bracket needs at least two images")
    for im in images:
        check_image(im)
    if len({(im.shape, im.dtype) for im in images}) != 1:
        raise ValueError("bracketed images must share size, channels and dtype")
    dtype = images[0].dtype
    if align:
        images = _align(images)
    if method == "mertens":
        scale = 255.0 / max_value(dtype)  # MergeMertens divides by 255 whatever the input depth
        stack = [_bgr(im) if dtype == np.uint8 else _bgr(im).astype(np.float32) * scale for im in images]
        fused = cv2.createMergeMertens().process(stack)
        return from_float(np.clip(_bgr(fused), 0.0, 1.0), dtype)
    if method == "debevec":
        if exposure_times is None or len(exposure_times) != len(images):
            raise ValueError("debevec merging needs one exposure time per image")
        if dtype != np.uint8:
            raise ValueError("debevec merging recovers an 8-bit camera response: give uint8 images")
        times = np.asarray(exposure_times, dtype=np.float32)
        stack = [np.ascontiguousarray(_bgr(im)) for im in images]
        response = cv2.createCalibrateDebevec().process(stack, times)
        radiance = cv2.createMergeDebevec().process(stack, times, response)
        return from_float(tone_map(_bgr(radiance)), dtype)
    raise ValueError(f"unknown merge method {method!r}; use 'mertens' or 'debevec'")


_REC709 = np.array([0.2126, 0.7152, 0.0722], np.float32)


def tone_map(radiance: np.ndarray, saturation: float = 0.6) -> np.ndarray:
    """Map linear radiance (HxW or HxWx3 RGB) to a display image in [0, 1] with local contrast.

    Log luminance is stretched between its 0.5th and 99.5th percentiles and equalised locally with
    CLAHE; colours are the radiance's chromaticity ratios raised to ``saturation``.
    """
    radiance = np.nan_to_num(radiance.astype(np.float32), nan=0.0, posinf=0.0)
    luminance = radiance if radiance.ndim == 2 else radiance @ _REC709
    positive = luminance[luminance > 0]
    floor = float(positive.min()) if positive.size else 1.0
    log = np.log2(np.maximum(luminance, floor))
    lo, hi = np.percentile(log, [0.5, 99.5])
    stretched = np.clip((log - lo) / max(hi - lo, 1e-6), 0.0, 1.0)
    local, _ = clahe(from_float(stretched, np.uint8), None, ClaheOptions())
    local = local.astype(np.float32) / 255.0
    if radiance.ndim == 2:
        return local
    ratio = np.clip(radiance / np.maximum(luminance, floor)[..., None], 0.0, 4.0)
    return np.clip(local[..., None] * ratio**saturation, 0.0, 1.0)


@dataclass(frozen=True)
class Bracket:
    """The images of one view at different exposures."""

    view: str
    paths: tuple[Path, ...]
    exposure_times: tuple[float, ...] | None  # seconds, from EXIF; None when a file has none


def exposure_time(path: str | Path) -> float | None:
    """EXIF ExposureTime of an image file in seconds, or None when it has none."""
    with Image.open(path) as image:
        value = image.getexif().get_ifd(_EXIF_IFD).get(_EXPOSURE_TIME)
    return None if value is None else float(value)


def _times(paths: Sequence[Path]) -> tuple[float, ...] | None:
    times = [exposure_time(p) for p in paths]
    return None if any(t is None for t in times) else tuple(times)


def group_by_exposure(paths: Sequence[str | Path], size: int = 0) -> list[Bracket]:
    """Split a capture-ordered sequence into brackets using EXIF exposure times.

    Auto-exposure bracketing shoots each view at distinct exposure times in a row, so a bracket
    ends when the next image repeats an exposure time already in it, or when it holds ``size``
    images (0 = no fixed size). Every image must carry ExposureTime.
    """
    brackets: list[Bracket] = []
    current: list[tuple[Path, float]] = []

    def close() -> None:
        if current:
            brackets.append(Bracket(view=current[0][0].stem, paths=tuple(p for p, _ in current),
                                    exposure_times=tuple(t for _, t in current)))
            current.clear()

    for raw in paths:
        path = Path(raw)
        t = exposure_time(path)
        if t is None:
            raise ValueError(f"{path} has no EXIF ExposureTime; group its brackets by name instead")
        if any(np.isclose(t, seen, rtol=1e-3) for _, seen in current) or (size and len(current) == size):
            close()
        current.append((path, t))
    close()
    return brackets


def group_by_name(paths: Sequence[str | Path], pattern: str) -> list[Bracket]:
    """Group images whose file names share the view id captured by ``pattern``.

    ``pattern`` is a regular expression searched in the file name, with a group named ``view`` or
    else its first group giving the view id, e.g. ``r"(.+)_ev[-+]?\\d+"`` for ``IMG7_ev-2.jpg``.
    Brackets come in order of first appearance; exposure times are read from EXIF when every
    image of a bracket has one.
    """
    regex = re.compile(pattern)
    groups: dict[str, list[Path]] = {}
    for raw in paths:
        path = Path(raw)
        match = regex.search(path.name)
        if match is None:
            raise ValueError(f"file name {path.name!r} does not match the bracket pattern {pattern!r}")
        view = match.group("view") if "view" in regex.groupindex else match.group(1)
        groups.setdefault(view, []).append(path)
    return [Bracket(view=view, paths=tuple(ps), exposure_times=_times(ps)) for view, ps in groups.items()]
