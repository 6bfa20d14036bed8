"""The frame every output is written in: up along +Z.

COLMAP's mapper leaves a model in the frame of its first camera (x right, y down, z forward), so a
model of level, handheld photos has its up along -Y, and glTF viewers (Y up) show it upside down.
A model without GPS is rotated about the origin so that the photos' average up
(:func:`recon.geometry.transforms.up_direction`) is +Z, the same convention as the local ENU frame
of a georeferenced model; exports that use another convention (glTF: Y up) convert from it.
"""

from __future__ import annotations

import numpy as np

from recon.geometry.transforms import level_rotation, up_direction


def level_model(rec) -> np.ndarray:
    """Rotate a pycolmap Reconstruction in place so that its photos' up is +Z; returns the rotation
    (new-from-old world) applied."""
    import pycolmap

    images = [image for image in rec.images.values() if image.has_pose]
    if not images:
        return np.eye(3)
    rotations = np.stack([image.cam_from_world().rotation.matrix() for image in images])
    centers = np.stack([image.projection_center() for image in images])
    rotation = level_rotation(up_direction(rotations, centers))
    rec.transform(pycolmap.Sim3d(1.0, pycolmap.Rotation3d(rotation), np.zeros(3)))
    return rotation
