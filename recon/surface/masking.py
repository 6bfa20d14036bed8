"""Masks on the surface: no face where the photos' masks say "not the subject".

Depth maps already leave masked pixels out, but Poisson closes the surface across the holes it
finds, so a mesh of a masked object can still hold faces over the background. A face is dropped
when a view that sees it (its centre in front of that view's first hit, by ray casting the mesh)
has its centre on a masked pixel more than ``EDGE_TOLERANCE`` px from the subject. Dropping faces shows
what lay behind them, so the test is repeated until no face goes (a few rounds).

The tolerance: every face of an object lies on the silhouette of some view, and there the mesh's own
error (a pixel or so) puts a face on the background side as often as not. Without it, on the zoo's
masked_object (640x480, 24 views) the test took 4,253 faces, all within a pixel of the mask's edge:
speckled holes over the object's weakly textured base and a one-pixel rim off its outline (held-out
coverage .906); with one pixel it takes none there (coverage .922, F unchanged), and faces over the
background a pixel or more beyond the outline still go.
"""

from __future__ import annotations

import numpy as np
import trimesh

from recon.imaging.masks import mask_at
from recon.mvs.views import ViewCamera
from recon.surface.cleanup import keep_faces
from recon.surface.raycast import cast_size, points_in_view, scene_of

#: a face centre counts as seen when it lies at most this far (relative) behind the view's first hit
DEPTH_TOLERANCE = 1e-3
#: a face centre on a masked pixel at most this far (px at the ray-cast size) from the subject is kept
EDGE_TOLERANCE = 1


def masked_faces(vertices: np.ndarray, faces: np.ndarray, views: list[ViewCamera],
                 masks: dict[str, np.ndarray]) -> np.ndarray:
    """Boolean per face: some view with a mask sees the face's centre on a masked pixel more than
    ``EDGE_TOLERANCE`` px from the subject."""
    scene = scene_of(vertices, faces)
    centres = vertices[faces].mean(axis=1)
    bad = np.zeros(len(faces), bool)
    for view in views:
        mask = masks.get(view.name)
        if mask is not None:
            bad[seen_on(scene, centres, view, ~_grown(mask_at(mask, *cast_size(view))))] = True
    return bad


def seen_on(scene, points: np.ndarray, view: ViewCamera, mask: np.ndarray) -> np.ndarray:
    """Indices of the ``points`` (N, 3; face centres of the mesh ray cast in ``scene``) that ``view`` sees
    (in front of its first hit on the mesh) on a True pixel of ``mask`` (bool, any resolution)."""
    at = points_in_view(scene, view, points)
    idx = np.flatnonzero(at["inside"] & (at["z"] <= at["first"] * (1 + DEPTH_TOLERANCE)))
    shown = mask_at(mask, at["width"], at["height"])
    return idx[shown[at["row"][idx], at["col"][idx]]]


def _grown(subject: np.ndarray) -> np.ndarray:
    """The subject's pixels and those within ``EDGE_TOLERANCE`` px of them (chessboard distance)."""
    import cv2

    size = 2 * EDGE_TOLERANCE + 1
    return cv2.dilate(subject.astype(np.uint8), np.ones((size, size), np.uint8)).astype(bool)


def drop_masked_faces(mesh: trimesh.Trimesh, views: list[ViewCamera], masks: dict[str, np.ndarray],
                      rounds: int = 4) -> tuple[trimesh.Trimesh, int]:
    """The mesh without the faces :func:`masked_faces` finds (repeated up to ``rounds`` times), and how
    many faces went."""
    dropped = 0
    for _ in range(rounds):
        bad = masked_faces(np.asarray(mesh.vertices), np.asarray(mesh.faces), views, masks)
        if not bad.any():
            break
        dropped += int(bad.sum())
        mesh = keep_faces(mesh, ~bad)
    return mesh, dropped
