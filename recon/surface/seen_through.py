"""Mesh faces the photos see through are dropped, where what the photos saw behind them is in the mesh.

Poisson extends and closes the surface past the fused points: a fringe of ground standing along a wall's
top edge, a skin under a balcony, a bridge from a rail down to the ground. The views that look past such a
face hold a depth beyond it. The test is the fused points' (:mod:`recon.mvs.free_space`) applied to the
faces' centres: a face is contradicted when more views see through it than agree with it.

A contradicted face goes only where at least half of the views that see through it find the mesh behind
it (a ray from just past the face, along the view's line of sight, hits the mesh): dropping it uncovers
surface the views measured. Where nothing of the mesh lies behind it (under a balcony, where the wall the
photos saw was never meshed), dropping it opens a hole through the model, and the face stays, painted by
the texture with what the photos saw through it. Dropping those too lost held-out coverage on the zoo
(facade_walk .9997 -> .9932) for little more mesh accuracy (docs/DECISIONS.md).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import trimesh

from recon.geometry.transforms import camera_center
from recon.mvs.free_space import AGREE, MARGIN, free_space_counts
from recon.mvs.views import ViewCamera
from recon.surface.raycast import cast, scene_of

#: the ray looking for the mesh behind a face starts this far (relative to the face's distance) past it
BEHIND = 0.02


def seen_through_faces(mesh: trimesh.Trimesh, views: Iterable[tuple[ViewCamera, np.ndarray]]) -> np.ndarray:
    """Boolean per face of ``mesh``: more of ``views`` (camera, its depth map) see through its centre than
    agree with it, and at least half of those that see through it find the mesh behind it (module doc)."""
    centres = np.asarray(mesh.triangles_center, np.float64)
    scene = scene_of(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    agreeing = np.zeros(len(centres), np.int32)
    through = np.zeros(len(centres), np.int32)
    uncovering = np.zeros(len(centres), np.int32)
    for cam, depth in views:
        agree, see = free_space_counts(centres, [(cam, depth)], AGREE, MARGIN)
        agreeing += agree
        through += see
        hit = np.flatnonzero(see)
        if len(hit):
            uncovering[hit] += mesh_behind(scene, centres[hit], cam)
    return (through > agreeing) & (2 * uncovering >= through)


def mesh_behind(scene, points: np.ndarray, cam: ViewCamera) -> np.ndarray:
    """Per point of ``points`` (N, 3) on the mesh ray cast in ``scene``: whether a ray from just past it
    (``BEHIND``, relative to its distance from ``cam``), along ``cam``'s line of sight, hits the mesh."""
    ray = points - camera_center(cam.R, cam.t)
    distance = np.linalg.norm(ray, axis=1, keepdims=True)
    ray /= distance
    return cast(scene, points + ray * (BEHIND * distance), ray)["face"] >= 0
