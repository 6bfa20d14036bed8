"""Reading photos for reconstruction: which files are photos, their size, EXIF focal and orientation.

COLMAP reads pixels with its own loader, which ignores EXIF orientation and expects 8-bit grey or
RGB. :func:`inspect_photo` finds what a file needs; :func:`normalized_copy` writes an 8-bit,
upright, alpha-free copy when it needs one, so every later stage sees the same pixels.
"""

from __future__ import annotations

import logging
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

log = logging.getLogger(__name__)

PHOTO_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
# EXIF tag numbers
_ORIENTATION, _FOCAL, _FOCAL_35MM = 0x0112, 0x920A, 0xA405
_FP_XRES, _FP_UNIT = 0xA20E, 0xA210
_EXIF_IFD = 0x8769
Image.MAX_IMAGE_PIXELS = 400_000_000  # allow large aerial frames; bounded by max_image_size later


class PhotoError(ValueError):
    """A file that is named like a photo but cannot be read as one."""


@dataclass
class PhotoInfo:
    name: str  # path relative to the image folder, '/'-separated
    width: int  # after EXIF rotation
    height: int
    mode: str
    orientation: int
    focal_px: float | None  # from EXIF, in pixels of the upright image
    needs_copy: bool  # not 8-bit grey/RGB, or rotated by EXIF


def list_photos(folder: Path) -> tuple[list[Path], list[Path]]:
    """Photos under ``folder`` (recursively, sorted) and the other files that were skipped."""
    photos, others = [], []
    for path in sorted(folder.rglob("*")):
        if path.is_dir() or any(part.startswith(".") for part in path.relative_to(folder).parts):
            continue
        (photos if path.suffix.lower() in PHOTO_SUFFIXES else others).append(path)
    return photos, others


def inspect_photo(path: Path, name: str) -> PhotoInfo:
    """Size, mode, EXIF orientation and focal of a photo; decodes it (cheaply) to catch corrupt files."""
    if path.stat().st_size == 0:
        raise PhotoError(f"{path}: empty file (0 bytes)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                exif = img.getexif()
                mode, (w, h) = img.mode, img.size
                if img.format == "JPEG":
                    img.draft("L", (max(1, w // 8), max(1, h // 8)))  # full scan at 1/8 scale
                img.load()
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as exc:
        raise PhotoError(f"{path}: cannot read image ({exc}); remove or replace the file") from None
    orientation = int(exif.get(_ORIENTATION, 1) or 1)
    if orientation in (5, 6, 7, 8):
        w, h = h, w
    return PhotoInfo(name=name, width=w, height=h, mode=mode, orientation=orientation,
                     focal_px=_exif_focal_px(exif, w, h),
                     needs_copy=mode not in ("L", "RGB") or orientation not in (0, 1))


def stored_size(path: Path) -> tuple[int, int]:
    """(width, height) as stored (before EXIF rotation), from the file's header: no pixel is decoded."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                return img.size
    except (UnidentifiedImageError, OSError) as exc:
        raise PhotoError(f"{path}: cannot read image ({exc}); remove or replace the file") from None


def _exif_focal_px(exif: Image.Exif, width: int, height: int) -> float | None:
    """Focal length in pixels from EXIF: the 35 mm equivalent, else focal / sensor resolution."""
    sub = exif.get_ifd(_EXIF_IFD) if hasattr(exif, "get_ifd") else {}
    tags = {**dict(exif), **dict(sub)}
    f35 = _num(tags.get(_FOCAL_35MM))
    if f35 and f35 > 0:  # 35 mm equivalent relates diagonals: 43.27 mm is the 36x24 mm frame's (CIPA DC-008)
        return f35 / 43.267 * float(np.hypot(width, height))
    focal, xres, unit = _num(tags.get(_FOCAL)), _num(tags.get(_FP_XRES)), tags.get(_FP_UNIT)
    if focal and xres and unit in (2, 3, 4, 5):
        mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}[unit]
        return focal * xres / mm_per_unit
    return None


def _num(value) -> float | None:
    try:
        return float(value) if value is not None else None
    except (TypeError, ValueError, ZeroDivisionError):
        return None


def read_upright(path: Path) -> Image.Image:
    """The photo as an upright 8-bit grey or RGB Pillow image (alpha dropped, 16-bit scaled)."""
    with Image.open(path) as img:
        img = ImageOps.exif_transpose(img)
        if img.mode in ("I;16", "I;16B", "I;16L", "I"):
            arr = np.asarray(img, dtype=np.float64)
            peak = 65535.0 if arr.max() > 255 else 255.0
            return Image.fromarray(np.clip(arr / peak * 255.0 + 0.5, 0, 255).astype(np.uint8), "L")
        if img.mode in ("L", "RGB"):
            return img.copy()
        if img.mode in ("LA", "La"):
            return img.convert("L")
        return img.convert("RGB")


def normalized_copy(src: Path, dest: Path) -> None:
    """Write the upright 8-bit version of ``src`` to ``dest`` (same format as ``dest``'s suffix)."""
    img = read_upright(src)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.tmp{dest.suffix}")
    params = {"quality": 95} if dest.suffix.lower() in (".jpg", ".jpeg") else {}
    img.save(tmp, **params)
    tmp.replace(dest)
