"""Reading photos for reconstruction: which files are photos, their size, EXIF focal and orientation.

COLMAP reads pixels with its own loader, which ignores EXIF orientation and expects 8-bit grey or
RGB. :func:`inspect_photo` finds what a file needs; :func:`normalized_copy` writes an 8-bit,
upright, alpha-free copy when it needs one, so every later stage sees the same pixels.
"""

from __future__ import annotations

import errno
import logging
import os
import stat
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from recon.files import atomic
from recon.geometry.gps import GpsTag, read_gps
from recon.sparse import lens

log = logging.getLogger(__name__)

PHOTO_SUFFIXES = {".jpg", ".jpeg", ".png", ".tif", ".tiff"}
# EXIF tag numbers
_ORIENTATION, _FOCAL, _FOCAL_35MM = 0x0112, 0x920A, 0xA405
_FP_XRES, _FP_UNIT = 0xA20E, 0xA210
_EXIF_IFD = 0x8769
_XMP_TIFF = 0x02BC  # TIFF's XMLPacket tag
#: an EXIF focal length is used only where it gives a diagonal field of view in this range (degrees):
#: beyond it the tag is broken (0, negative, 1e9 mm), and a wrong prior is worse than none
FOV_RANGE_DEG = (10.0, 170.0)
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
    gps: GpsTag | None = None  # EXIF GPS (and drone XMP)
    projection: str = "perspective"  # the lens by its metadata: perspective, fisheye, equirectangular (lens.py)


@dataclass
class Listing:
    """What a photo folder holds: photos, other files, and entries that cannot be read as files."""

    photos: list[Path] = field(default_factory=list)
    others: list[Path] = field(default_factory=list)  # regular files that are not JPEG/PNG/TIFF
    unreadable: list[tuple[Path, str]] = field(default_factory=list)  # (entry, why it is skipped)


def list_photos(folder: Path, exclude: Callable[[Path], bool] | None = None) -> Listing:
    """The photos under ``folder`` (recursively, sorted), the other files, and what cannot be read.

    Only regular files are ever listed as photos: reading a FIFO or a device named ``x.jpg`` would
    block forever, so they, sockets, dangling links, link loops, files that cannot be read and
    names that are not UTF-8 (COLMAP stores names as UTF-8 text) are set aside with the reason.
    Hidden entries are skipped, and so is whatever ``exclude`` names (a workspace's own outputs when
    the workspace lies in the photo folder), without descending into excluded folders.
    """
    listing = Listing()
    found: list[Path] = []
    for top, dirs, files in os.walk(folder):
        dirs[:] = [d for d in dirs if not d.startswith(".") and not (exclude and exclude(Path(top) / d))]
        found += [Path(top) / f for f in files if not f.startswith(".")]
    for path in sorted(found):
        if exclude and exclude(path):
            continue
        why = _unreadable(path, path.relative_to(folder).as_posix())
        if why:
            listing.unreadable.append((path, why))
        elif path.suffix.lower() in PHOTO_SUFFIXES:
            listing.photos.append(path)
        else:
            listing.others.append(path)
    return listing


def _unreadable(path: Path, name: str) -> str | None:
    """Why ``path`` cannot be read as a photo file, or None."""
    try:
        st = path.stat()
    except FileNotFoundError:
        return "dangling symbolic link"
    except OSError as exc:
        return "symbolic link loop" if exc.errno == errno.ELOOP else f"cannot be read ({exc.strerror})"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file (a FIFO, device or socket)"
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return "file name is not valid UTF-8; rename the file"
    if not os.access(path, os.R_OK):
        return "cannot be read (permission denied)"
    return None


def inspect_photo(path: Path, name: str) -> PhotoInfo:
    """Size, mode, EXIF orientation and focal of a photo; decodes it (cheaply) to catch corrupt files."""
    if path.stat().st_size == 0:
        raise PhotoError(f"{path}: empty file (0 bytes)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                exif = img.getexif()
                xmp = img.info.get("xmp") or img.info.get("XML:com.adobe.xmp") or exif.get(_XMP_TIFF)
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
                     focal_px=_exif_focal_px(exif, w, h, path),
                     needs_copy=mode not in ("L", "RGB") or orientation not in (0, 1),
                     gps=read_gps(exif, xmp, str(path)),
                     projection=lens.projection({**dict(exif), **dict(exif.get_ifd(_EXIF_IFD))}, xmp, w, h))


def stored_size(path: Path) -> tuple[int, int]:
    """(width, height) as stored (before EXIF rotation), from the file's header: no pixel is decoded."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with Image.open(path) as img:
                return img.size
    except (UnidentifiedImageError, OSError) as exc:
        raise PhotoError(f"{path}: cannot read image ({exc}); remove or replace the file") from None


def _exif_focal_px(exif: Image.Exif, width: int, height: int, path: Path) -> float | None:
    """Focal length in pixels from EXIF: the 35 mm equivalent, else focal / sensor resolution.

    A value that is not a positive number or gives a diagonal field of view outside FOV_RANGE_DEG is
    ignored with a warning naming the photo (sfm then starts from a guess and refines it).
    """
    sub = exif.get_ifd(_EXIF_IFD) if hasattr(exif, "get_ifd") else {}
    tags = {**dict(exif), **dict(sub)}
    diagonal = float(np.hypot(width, height))
    candidates: list[tuple[str, float | None]] = []  # (the tag as read, focal in pixels where known)
    f35 = _num(tags.get(_FOCAL_35MM))
    if f35 is not None and f35 != 0:  # 0 is EXIF's "unknown"
        # 35 mm equivalent relates diagonals: 43.27 mm is the 36x24 mm frame's (CIPA DC-008)
        candidates.append((f"FocalLengthIn35mmFilm {f35:g} mm", f35 / 43.267 * diagonal))
    focal, xres, unit = _num(tags.get(_FOCAL)), _num(tags.get(_FP_XRES)), tags.get(_FP_UNIT)
    if focal is not None:
        known = bool(xres) and unit in (2, 3, 4, 5)
        mm_per_unit = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}.get(unit, 1.0)
        candidates.append((f"FocalLength {focal:g} mm", focal * xres / mm_per_unit if known else None))
    lo, hi = FOV_RANGE_DEG
    rejected, chosen = [], None
    for tag, px in candidates:
        if px is None:  # no sensor size: a focal in mm cannot be turned into pixels, only checked
            if not focal > 0 or not np.isfinite(focal):
                rejected.append(tag)
            continue
        fov = float(np.degrees(2 * np.arctan2(diagonal / 2, px)))
        if lo <= fov <= hi:
            chosen = px
            break
        rejected.append(tag)
    if rejected:
        log.warning("%s: EXIF %s: not a focal length giving a %g to %g degree field of view; ignored%s", path,
                    ", ".join(rejected), lo, hi, "" if chosen else " (sfm estimates the focal length)")
    return chosen


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
    params = {"quality": 95} if dest.suffix.lower() in (".jpg", ".jpeg") else {}
    with atomic(dest) as tmp:
        img.save(tmp, **params)
