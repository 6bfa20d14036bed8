"""What kind of lens took a photo, from its metadata, and which COLMAP camera model fits it.

- ``fisheye``: EXIF LensModel names a fisheye, or the 35 mm equivalent focal length
  (FocalLengthIn35mmFilm) is below :data:`FISHEYE_35MM_BELOW` mm: a rectilinear lens that short is
  rare, a fisheye common (a 176 degree diagonal fisheye on a full frame is 14 mm).
- ``equirectangular``: a 2:1 photo whose XMP carries ``GPano:ProjectionType`` "equirectangular", as
  360-degree cameras and Google's photo-sphere tools write it.
- ``perspective``: everything else.

``ingest.camera_model: auto`` takes :data:`AUTO_MODELS` of the photos' projection. The 35 mm
equivalent is the focal length scaled by the crop factor (what cameras write), so it gives the
focal in pixels as ``f35 / 43.27 mm x the image diagonal`` for a fisheye as for a pinhole
(:func:`recon.sparse.photos.inspect_photo` reads it so); only the field of view it means differs
(equidistant fisheye: diagonal / f radians, pinhole: 2 atan(diagonal / 2 f)).
"""

from __future__ import annotations

import re

PROJECTIONS = ("perspective", "fisheye", "equirectangular")
FISHEYE_35MM_BELOW = 14.0
AUTO_MODELS = {"perspective": "SIMPLE_RADIAL", "fisheye": "OPENCV_FISHEYE", "equirectangular": "EQUIRECTANGULAR"}
#: COLMAP's fisheye models recon offers (all equidistant at zero distortion)
FISHEYE_MODELS = ("SIMPLE_FISHEYE", "FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE")
SPHERICAL_MODELS = ("EQUIRECTANGULAR",)

_LENS_MODEL = 0xA434
_FOCAL_35MM = 0xA405
_GPANO = re.compile(rb"GPano:ProjectionType\s*(?:=\s*[\"']|>)\s*equirectangular", re.IGNORECASE)


def projection(tags: dict, xmp: bytes | str | None, width: int, height: int) -> str:
    """The projection a photo's metadata says (``tags``: EXIF tag number -> value, the main and the
    Exif IFD merged; ``xmp``: the XMP packet, or None)."""
    if isinstance(xmp, str):
        xmp = xmp.encode("utf-8", "replace")
    if isinstance(xmp, bytes) and width == 2 * height and _GPANO.search(xmp):
        return "equirectangular"
    lens = tags.get(_LENS_MODEL)
    if isinstance(lens, bytes):
        lens = lens.decode("latin-1")
    if isinstance(lens, str) and "fisheye" in lens.lower().replace("-", "").replace(" ", ""):
        return "fisheye"
    try:
        f35 = float(tags.get(_FOCAL_35MM) or 0)
    except (TypeError, ValueError, ZeroDivisionError):
        f35 = 0.0
    if 0 < f35 < FISHEYE_35MM_BELOW:
        return "fisheye"
    return "perspective"


def auto_model(projections: list[str]) -> str:
    """The camera model for a group of photos: that of their most common projection."""
    most = max(PROJECTIONS, key=projections.count)
    return AUTO_MODELS[most]


def model_warning(model: str, projections: list[str], sizes: list[tuple[int, int]]) -> str | None:
    """Why ``model`` looks wrong for photos with these projections and sizes, with what to set; or None."""
    n = len(projections)
    fisheye, spherical = projections.count("fisheye"), projections.count("equirectangular")
    if spherical and model not in SPHERICAL_MODELS:
        return (f"{spherical} of {n} photos are 360-degree panoramas (XMP GPano equirectangular) but "
                f"ingest.camera_model is {model}: set it to EQUIRECTANGULAR (or auto)")
    if fisheye and model not in FISHEYE_MODELS:
        return (f"{fisheye} of {n} photos were taken with a fisheye lens (EXIF lens model or 35 mm focal "
                f"length) but ingest.camera_model is {model}: set it to OPENCV_FISHEYE (or auto)")
    if model not in SPHERICAL_MODELS and sizes and all(w == 2 * h for w, h in sizes):
        return (f"all {n} photos are twice as wide as high: if they are 360-degree panoramas, set "
                "ingest.camera_model to EQUIRECTANGULAR")
    return None


#: widest diagonal field of view a fitted pinhole-family camera may span before it reads as a fisheye
#: forced into a pinhole model (rectilinear lenses that wide are rare: a 12 mm full-frame lens spans 122)
MAX_PINHOLE_FOV_DEG = 130.0


def pinhole_fit_warning(camera) -> str | None:
    """Why a camera fitted with a pinhole-family model (a pycolmap Camera of a finished model) looks
    like a fisheye or 360 lens forced into it, with what to set; or None. Symptoms: its distortion
    folds back before the photo's corners (no ray reaches them), or it spans more than
    MAX_PINHOLE_FOV_DEG across the diagonal. Measured on the synthetic 176-degree fisheye orbit:
    SIMPLE_RADIAL fits f = 195 px, k = -0.072 on 640 x 480, whose radius peaks at 279 px, short of
    the corners' 400 px; every photo registers, with AUC@5 7.7."""
    import numpy as np

    if not camera.is_perspective_pinhole():
        return None
    w, h = camera.width, camera.height
    xy = camera.cam_from_img(np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]))
    if not np.all(np.isfinite(xy)):
        symptom = "its fitted distortion folds back before the photo's corners"
    else:
        fov = 2 * np.degrees(np.arctan(np.linalg.norm(xy, axis=1).max()))
        if fov <= MAX_PINHOLE_FOV_DEG:
            return None
        symptom = f"it spans {fov:.0f} degrees across the diagonal"
    return (f"camera {camera.camera_id} ({camera.model.name}): {symptom}: the photos look like a fisheye (or "
            "360-degree) lens that a pinhole model cannot fit, and the poses are likely wrong; set "
            "ingest.camera_model to OPENCV_FISHEYE (360-degree panoramas: EQUIRECTANGULAR)")
