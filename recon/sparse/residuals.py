"""Reprojection errors of a sparse model's observations, computed from its points, poses and cameras.

pycolmap keeps one error per point (its track's mean), refreshed only by some of its steps; the final
BA's refinement tests (:mod:`recon.sparse.mapping`) and the report's per-photo errors need them per
observation, as the model stands.
"""

from __future__ import annotations

import numpy as np


def observation_errors(rec, image) -> np.ndarray:
    """The reprojection error (pixels) of each observation of the registered ``image`` of ``rec`` that
    has a 3D point, in the order of its points2D; NaN where the camera cannot project the point."""
    seen = [p for p in image.points2D if p.has_point3D()]
    if not seen:
        return np.zeros(0)
    pose = image.cam_from_world()
    world = np.array([rec.point3D(p.point3D_id).xyz for p in seen])
    projected = np.asarray(rec.camera(image.camera_id).img_from_cam(world @ pose.rotation.matrix().T + pose.translation))
    return np.linalg.norm(projected - np.array([p.xy for p in seen]), axis=1)
