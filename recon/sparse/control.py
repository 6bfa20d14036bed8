"""Points a user marks in photos (scale-bar ends, ground control points), triangulated with a model's
cameras.

Pixel positions are in the photos as the model's cameras see them (upright, as ingest presents
them) and, as users read them off an image viewer, whole numbers at pixel centres; a photo is named
as in ``images.json`` (its path under the photo folder) or by its file name alone where that is
unique. The point is COLMAP's multi-view triangulation of the observations' rays
(``pycolmap.triangulate_multi_view_point``: any camera model, fisheye and 360 included); its
reprojection error in each photo tells a mistyped click from a good one.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recon.options import opt


@dataclass(frozen=True)
class BarEnd:
    """Where a photo sees one end of a scale bar."""

    photo: str = opt("", "photo name (as in images.json: its path under the photo folder)")
    x: float = opt(0.0, "pixel column (0 = the centre of the leftmost pixel)")
    y: float = opt(0.0, "pixel row (0 = the centre of the top pixel)")


@dataclass(frozen=True)
class ScaleBar:
    """A known distance between two points, each marked in at least two photos."""

    length: float = opt(0.0, "the distance between the two points, metres", ge=0)
    a: list[BarEnd] = opt([], "where photos see the first point (two photos or more)")
    b: list[BarEnd] = opt([], "where photos see the second point (two photos or more)")


class ControlError(ValueError):
    """Marked points that cannot be used; the message says which and why."""


@dataclass(frozen=True, eq=False)
class Triangulated:
    xyz: np.ndarray  # (3,) in the model's frame
    photos: list[str]  # the registered photos whose observations were used
    reprojection_px: np.ndarray  # (len(photos),) distance between each observation and the point's projection
    unregistered: list[str]  # photos named that the model does not hold (not used)


def triangulate(model, observations: Sequence[tuple[str, float, float]]) -> Triangulated:
    """Triangulate one point from ``(photo, x, y)`` observations (pixel coordinates, the top-left
    pixel's centre at (0, 0); COLMAP puts it at (0.5, 0.5)) in a pycolmap Reconstruction. Raises
    :class:`ControlError` when fewer than two registered photos see it, a position lies outside its
    photo, or the rays do not meet in front of the cameras."""
    import pycolmap

    images = _images_by_name(model)
    used, unregistered, poses, rays, pixels = [], [], [], [], []
    for name, column, row in observations:
        x, y = column + 0.5, row + 0.5  # COLMAP's pixel coordinates
        image = images.get(name)
        if image is None:
            unregistered.append(name)
            continue
        camera = model.camera(image.camera_id)
        if not (0 <= x <= camera.width and 0 <= y <= camera.height):
            raise ControlError(f"{name}: pixel ({x - 0.5:g}, {y - 0.5:g}) is outside the photo "
                               f"({camera.width}x{camera.height})")
        used.append(image.name)
        poses.append(image.cam_from_world())
        rays.append(camera.cam_ray_from_img(np.array([x, y], dtype=float)))
        pixels.append((x, y))
    if len(used) < 2:
        raise ControlError(f"seen in {len(used)} registered photo(s)" +
                           (f" ({', '.join(unregistered)} not registered)" if unregistered else "") +
                           "; at least two are needed")
    xyz = pycolmap.triangulate_multi_view_point([p.matrix() for p in poses], np.array(rays, dtype=float))
    if xyz is None:
        raise ControlError(f"the rays from {', '.join(used)} do not meet")
    xyz = np.asarray(xyz, dtype=float).reshape(3)
    errors = []
    for pose, k in zip(poses, range(len(used))):
        in_camera = pose * xyz
        camera = model.camera(images[used[k]].camera_id)
        projected = camera.img_from_cam(in_camera) if in_camera[2] > 0 else None
        if projected is None:
            raise ControlError(f"the rays meet behind {used[k]}: check its pixel position")
        errors.append(float(np.linalg.norm(np.asarray(projected).reshape(2) - pixels[k])))
    return Triangulated(xyz, used, np.array(errors), unregistered)


def _images_by_name(model) -> dict:
    """Registered images by name, and by file name alone where that is unique."""
    images = [model.image(i) for i in model.reg_image_ids()]
    by_name = {image.name: image for image in images}
    short: dict[str, list] = {}
    for image in images:
        short.setdefault(image.name.rsplit("/", 1)[-1], []).append(image)
    for name, found in short.items():
        if len(found) == 1:
            by_name.setdefault(name, found[0])
    return by_name
