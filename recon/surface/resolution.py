"""How finely the photos show a mesh: each face's area in pixels in the view that shows it largest.

The mesh stage decimates to a fixed face count (``mesh.target_faces``). A wide scene then keeps faces
several pixels across, but an object a few hundred pixels across in each photo keeps several vertices
per pixel: stereo measures no shape that fine (its matching window is several pixels wide), so the
extra vertices carry only noise and weight, and the vertex colours they hold are a copy of the photos'
pixels rather than a coarse stand-in for the texture. ``mesh.max_faces_per_pixel`` decimates such a
mesh further, to that many faces per pixel of its surface in the views that show it closest.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import trimesh

from recon.geometry.transforms import project
from recon.mvs.views import ViewCamera
from recon.surface.unseen import face_geometry, seen_by


def best_view_pixels(mesh: trimesh.Trimesh, views: Iterable[ViewCamera]) -> np.ndarray:
    """Per face, its area in pixels (at each view's full size) in the view that shows it largest, among the
    views that see it (:func:`recon.surface.unseen.seen_by`); 0 where none does."""
    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces)
    scene, centres, normals = face_geometry(vertices, faces)
    best = np.zeros(len(faces))
    for view in views:
        _, seen = seen_by(scene, view, centres, normals)
        uv = project(view.K, view.R, view.t, vertices)[0][faces]  # faces x 3 x 2
        a, b = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        area = 0.5 * np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
        best = np.maximum(best, np.where(seen, area, 0.0))
    return best


def resolved_faces(mesh: trimesh.Trimesh, views: Iterable[ViewCamera], faces_per_pixel: float) -> int:
    """How many faces the mesh needs at ``faces_per_pixel`` faces per pixel of its surface in the views
    that show it largest (:func:`best_view_pixels`)."""
    return int(np.ceil(faces_per_pixel * best_view_pixels(mesh, views).sum()))
