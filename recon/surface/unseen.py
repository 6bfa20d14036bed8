"""Mesh faces no photo sees are dropped.

Poisson closes the surface and extends it past the fused points: over the hidden side of an object, under
a balcony, behind a corner no photo looks round. Nothing in the photos supports such a face, the texture
can only fill it with its neighbours' colours, and most of it is off the true surface. A view *sees* a
face when the face's centre lies in its frame, at most ``DEPTH_TOLERANCE`` (relative) behind the view's
first hit there (ray casting the mesh itself), and the face turns towards the camera.

A face next to a seen face (sharing an edge) stays: on a noisy surface seen at a grazing angle (a meadow
80 m off), the far slopes of its bumps face away from every view but lie on the true surface, and dropping
them would pepper it with holes.

The depth tolerance is relative, so it grows with distance as the views' depth precision does, and a
small face whose centre falls between two pixels' rays still counts as seen at a grazing angle (the
masking test, which condemns faces, asks 0.1 %; this test spares them, and asks 1 %).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import trimesh

from recon.geometry.transforms import camera_center
from recon.mvs.views import ViewCamera
from recon.surface.cleanup import keep_faces
from recon.surface.raycast import points_in_view, scene_of

#: a face centre at most this far (relative) behind a view's first hit counts as seen by the view
DEPTH_TOLERANCE = 0.01


def seen_faces(vertices: np.ndarray, faces: np.ndarray, views: list[ViewCamera]) -> np.ndarray:
    """Boolean per face: some view sees it (module doc)."""
    scene = scene_of(vertices, faces)
    tri = vertices[faces]
    centres = tri.mean(axis=1)
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    seen = np.zeros(len(faces), bool)
    for view in views:
        at = points_in_view(scene, view, centres)
        facing = np.einsum("ij,ij->i", normals, camera_center(view.R, view.t) - centres) > 0
        seen |= at["inside"] & facing & (at["z"] <= at["first"] * (1 + DEPTH_TOLERANCE))
    return seen


def drop_unseen_faces(mesh: trimesh.Trimesh, views: list[ViewCamera]) -> tuple[trimesh.Trimesh, int]:
    """The mesh without the faces no view sees and none of whose edge neighbours a view sees, and how many
    faces went."""
    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        return mesh, 0
    seen = seen_faces(np.asarray(mesh.vertices, np.float64), faces, views)
    pairs = np.asarray(mesh.face_adjacency)
    if len(pairs):
        adjacency = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(faces),) * 2)
        seen |= (adjacency + adjacency.T) @ seen.astype(np.float64) > 0
    dropped = int(np.count_nonzero(~seen))
    return (keep_faces(mesh, seen) if dropped else mesh), dropped
