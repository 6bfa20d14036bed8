"""Outputs of localization: the reference model with the placed photos added, and ``poses.json``.

The photos are ADDED: each placed photo gets a new camera (the intrinsics its pose was estimated
with, in a trivial rig of its own) and a new image holding its keypoints as 2D points, with the
estimated pose. Nothing of the reference changes: its cameras, images, poses and 3D points (tracks
included: the new 2D points are not linked to them) are written back as they were read.
"""

from __future__ import annotations

import logging

import numpy as np

from recon.localize.pose import Photo, Placement

log = logging.getLogger(__name__)


def add_placed(reconstruction, placements: list[Placement], photos: dict[str, Photo]) -> dict[str, int]:
    """Add every placed photo to ``reconstruction`` (in place); returns photo name -> new image id.

    A photo named like an image of the reference is added as ``localized/<name>``.
    """
    import pycolmap

    rec = reconstruction
    taken = {img.name for img in rec.images.values()}
    next_camera = max([*rec.cameras, *rec.rigs, 0]) + 1
    next_image = max([*rec.images, *rec.frames, 0]) + 1
    added = {}
    for placement in placements:
        if not placement.placed:
            continue
        name = placement.name
        if name in taken:
            name = f"localized/{name}"
            log.warning("%s: the reference has an image of that name; added as %s", placement.name, name)
        camera = pycolmap.Camera(model=placement.camera_model, width=placement.width, height=placement.height,
                                 params=placement.params, camera_id=next_camera)
        rec.add_camera_with_trivial_rig(camera)
        keypoints = np.asarray(photos[placement.name].keypoints[:, :2], dtype=np.float64)
        image = pycolmap.Image(name=name, keypoints=keypoints, camera_id=next_camera, image_id=next_image)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(np.column_stack([placement.R, placement.t])))
        taken.add(name)
        added[placement.name] = next_image
        next_camera += 1
        next_image += 1
    return added


def poses_json(placements: list[Placement], image_ids: dict[str, int]) -> dict:
    """The content of ``poses.json``: counts, then one record per photo (see :meth:`Placement.to_json`)."""
    photos = []
    for p in placements:
        record = p.to_json()
        if p.name in image_ids:
            record["image_id"] = image_ids[p.name]
        photos.append(record)
    return {"convention": "qvec (w, x, y, z) and tvec map world to camera: x_cam = R(qvec) X + tvec; "
                          "centre = camera centre in world coordinates",
            "placed": sum(p.placed for p in placements), "total": len(placements), "photos": photos}
