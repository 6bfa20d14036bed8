"""The camera a new photo's pose is estimated with.

A photo from a camera of the reference is best served by that camera's calibration, refined by the
reference's bundle adjustment: ``auto`` takes the reference camera of the photo's aspect ratio
(the most used one), rescaled to the photo's size, unless the photo's EXIF focal says it is another
camera (or zoom setting). Otherwise the photo's own camera: its EXIF focal, or ingest's guess,
which is then estimated by RANSAC (P4Pf) and refined when ``estimate_focal`` is ``auto``.
"""

from __future__ import annotations

from dataclasses import dataclass

from recon.localize.options import LocalizeOptions
from recon.localize.reference import Reference
from recon.sparse.database import camera_params

#: largest relative difference of aspect ratios for a reference camera to be rescaled to a photo
ASPECT_TOLERANCE = 0.005


@dataclass(frozen=True)
class PhotoCamera:
    """What is known of a new photo's camera (ingest's record)."""

    width: int
    height: int
    focal: float  # pixels: EXIF, or a guess
    focal_from_exif: bool
    model: str = "SIMPLE_RADIAL"


@dataclass
class Intrinsics:
    camera: object  # pycolmap.Camera
    source: str  # where they come from, for the report
    estimate_focal: bool


def choose_intrinsics(photo: PhotoCamera, reference: Reference, options: LocalizeOptions) -> Intrinsics | str:
    """The camera to estimate the pose with, or the reason there is none (``intrinsics: reference``
    without a reference camera of the photo's aspect ratio)."""
    import pycolmap

    ref = None if options.intrinsics == "photo" else _reference_camera(photo, reference)
    if ref is not None and options.intrinsics == "auto" and photo.focal_from_exif:
        if abs(photo.focal - ref[0].mean_focal_length()) > options.focal_tolerance * ref[0].mean_focal_length():
            ref = None
    if ref is not None:
        camera, camera_id = ref
        return Intrinsics(camera, f"reference camera {camera_id}", options.estimate_focal == "always")
    if options.intrinsics == "reference":
        return (f"no reference camera has the photo's aspect ratio ({photo.width}x{photo.height}); "
                "use localize.intrinsics: photo")
    camera = pycolmap.Camera(model=photo.model, width=photo.width, height=photo.height,
                             params=camera_params(photo.model, photo.width, photo.height, photo.focal))
    camera.has_prior_focal_length = photo.focal_from_exif
    estimate = options.estimate_focal == "always" or (options.estimate_focal == "auto" and not photo.focal_from_exif)
    return Intrinsics(camera, "photo EXIF focal" if photo.focal_from_exif else "photo, focal guessed", estimate)


def _reference_camera(photo: PhotoCamera, reference: Reference):
    """(a copy rescaled to the photo's size, its id) of the reference camera with the photo's aspect
    ratio that most registered images use, or None."""
    import pycolmap

    rec = reference.reconstruction
    uses: dict[int, int] = {}
    for image_id in reference.image_ids:
        cam_id = rec.image(image_id).camera_id
        uses[cam_id] = uses.get(cam_id, 0) + 1
    aspect = photo.width / photo.height
    fitting = [c for c in uses if abs(rec.camera(c).width / rec.camera(c).height - aspect) <= ASPECT_TOLERANCE * aspect]
    if not fitting:
        return None
    camera_id = max(fitting, key=lambda c: (uses[c], -c))
    source = rec.camera(camera_id)
    camera = pycolmap.Camera(model=source.model, width=source.width, height=source.height, params=source.params)
    if (camera.width, camera.height) != (photo.width, photo.height):
        camera.rescale(photo.width, photo.height)
    camera.has_prior_focal_length = True
    return camera, camera_id
