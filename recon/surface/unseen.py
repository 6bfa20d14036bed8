"""Mesh faces no photo sees, or that photos see but nothing in them measures, are dropped.

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

Poisson also puts surface where several photos look and none of their depth maps found any: a wall
continued past its top into the sky, a car's outline kept after its points went. A face that at least
``unmeasured_views`` views see while none holds a depth at its pixel goes, unless some view finds it in a
hole of its depth map: depths within ``ENCLOSED_DEPTH`` of the face's own on ``ENCLOSED_SIDES`` of the
four sides of the pixel (left, right, above, below, however far). Three, not four: a hole at the photo's
edge (a road marking running out of the frame, a window cut by it) has no side beyond the edge. A window pane or a painted panel too even for stereo is
framed by surface that was measured, and Poisson's bridge over it is kept; sky beyond a wall's edge has
nothing above it.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import trimesh

from recon.geometry.transforms import camera_center
from recon.mvs.views import ViewCamera
from recon.surface.cleanup import face_graph, keep_faces
from recon.surface.raycast import points_in_view, scene_of

#: a face centre at most this far (relative) behind a view's first hit counts as seen by the view
DEPTH_TOLERANCE = 0.01
#: a face's pixel lies in a hole of a depth map when, on ENCLOSED_SIDES of its four sides, the nearest
#: depth lies within ENCLOSED_DEPTH (relative) of the face's own
ENCLOSED_DEPTH = 0.3
ENCLOSED_SIDES = 3


def _nearest_depths(depth: np.ndarray) -> list[np.ndarray]:
    """Per pixel of a depth map: the depth of the nearest pixel holding one to its left, right, above and
    below (0 where none does)."""
    out = []
    for axis in (1, 0):
        positions = np.arange(depth.shape[axis]).reshape((1, -1) if axis == 1 else (-1, 1))
        for flip in (False, True):
            d = np.flip(depth, axis) if flip else depth
            last = np.maximum.accumulate(np.where(d > 0, positions, -1), axis=axis)
            near = np.take_along_axis(d, np.maximum(last, 0), axis=axis) * (last >= 0)
            out.append(np.flip(near, axis) if flip else near)
    return out


def face_views(vertices: np.ndarray, faces: np.ndarray, views: Iterable[tuple[ViewCamera, np.ndarray | None]]
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per face, how many of ``views`` (camera, its depth map or None): see it (module doc); see it and hold
    a depth at its centre's pixel; see it and find depths within ``ENCLOSED_DEPTH`` of its own on
    ``ENCLOSED_SIDES`` sides of that pixel (a hole in the depth map, not its edge)."""
    scene, centres, normals = face_geometry(vertices, faces)
    counts = np.zeros((3, len(faces)), np.int32)
    for view, depth in views:
        at, seen = seen_by(scene, view, centres, normals)
        counts[0] += seen
        if depth is None:
            continue
        h, w = depth.shape
        rows = np.minimum(at["row"] * h // at["height"], h - 1)
        cols = np.minimum(at["col"] * w // at["width"], w - 1)
        counts[1] += seen & (depth[rows, cols] > 0)
        sides = np.zeros(len(faces), np.int32)
        for near in _nearest_depths(depth):
            side = near[rows, cols]
            sides += (side > 0) & (np.abs(side - at["z"]) <= ENCLOSED_DEPTH * at["z"])
        counts[2] += seen & (sides >= ENCLOSED_SIDES)
    return counts[0], counts[1], counts[2]


def face_geometry(vertices: np.ndarray, faces: np.ndarray) -> tuple[object, np.ndarray, np.ndarray]:
    """The mesh's ray-casting scene and its faces' centres and (unnormalised) normals, for :func:`seen_by`."""
    tri = vertices[faces]
    return scene_of(vertices, faces), tri.mean(axis=1), np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])


def seen_by(scene, view, centres: np.ndarray, normals: np.ndarray) -> tuple[dict, np.ndarray]:
    """Where the faces (their ``centres`` and ``normals``, N x 3; ``scene``: the mesh's ray-casting scene) lie
    in ``view`` (:func:`recon.surface.raycast.points_in_view`) and which of them it sees (module doc)."""
    at = points_in_view(scene, view, centres)
    facing = np.einsum("ij,ij->i", normals, camera_center(view.R, view.t) - centres) > 0
    return at, at["inside"] & facing & (at["z"] <= at["first"] * (1 + DEPTH_TOLERANCE))


def drop_unseen_faces(mesh: trimesh.Trimesh, views: Iterable[tuple[ViewCamera, np.ndarray | None]],
                      unmeasured_views: int = 0) -> tuple[trimesh.Trimesh, int, int]:
    """The mesh without the faces no view sees and none of whose edge neighbours a view sees, nor (with
    ``unmeasured_views``) those that many views see while none holds a depth there or finds them in a hole
    of its depth map; and how many faces went for each reason."""
    faces = np.asarray(mesh.faces)
    if len(faces) == 0:
        return mesh, 0, 0
    seeing, measuring, enclosing = face_views(np.asarray(mesh.vertices, np.float64), faces, views)
    seen = seeing > 0
    seen |= face_graph(mesh) @ seen.astype(np.float64) > 0
    unmeasured = np.zeros(len(faces), bool)
    if unmeasured_views:
        unmeasured = seen & (seeing >= unmeasured_views) & (measuring == 0) & (enclosing == 0)
    keep = seen & ~unmeasured
    if keep.all():
        return mesh, 0, 0
    return keep_faces(mesh, keep), int(np.count_nonzero(~seen)), int(np.count_nonzero(unmeasured))
