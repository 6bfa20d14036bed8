"""Mesh faces no view sees go (recon.surface.unseen): the hidden underside of an object, a surface
enclosed by another; faces next to a seen face stay."""

import numpy as np
import trimesh

from recon.mvs.views import ViewCamera
from recon.surface.unseen import drop_unseen_faces, seen_faces
from recon.synth.cameras import look_at


def _ring_of_views(elevation_deg: float, count: int = 8, distance: float = 5.0, size: int = 160) -> list[ViewCamera]:
    """``count`` cameras round the origin at ``elevation_deg``, looking at it."""
    views = []
    e = np.radians(elevation_deg)
    for k, a in enumerate(np.linspace(0, 2 * np.pi, count, endpoint=False)):
        centre = distance * np.array([np.cos(a) * np.cos(e), np.sin(a) * np.cos(e), np.sin(e)])
        R, t = look_at(centre, np.zeros(3))
        K = np.array([[size, 0, size / 2], [0, size, size / 2], [0, 0, 1.0]])
        views.append(ViewCamera(f"v{k}.jpg", K, R, t, size, size))
    return views


def _elevation(mesh: trimesh.Trimesh) -> np.ndarray:
    """Each face normal's elevation above the horizontal (degrees)."""
    return np.degrees(np.arcsin(np.clip(mesh.face_normals[:, 2], -1, 1)))


def test_the_underside_no_view_sees_goes_and_what_the_views_see_stays():
    """A unit sphere seen from 5 away at 40 degrees up: a view sees the faces whose normals lie within
    arccos(1/5) = 78.5 degrees of its direction, down to 38.5 degrees below the horizon, so the cap below
    that (19 % of the sphere) goes and everything above the horizon stays."""
    sphere = trimesh.creation.icosphere(subdivisions=4)
    views = _ring_of_views(40.0)
    kept, dropped = drop_unseen_faces(sphere, views)
    up = _elevation(sphere) > 0
    assert 0.1 * len(sphere.faces) < dropped < 0.2 * len(sphere.faces)
    assert np.count_nonzero(_elevation(kept) > 0) == np.count_nonzero(up)  # all of the top half stays
    assert _elevation(kept).min() > -48.0  # the bottom cap is gone
    seen = seen_faces(np.asarray(sphere.vertices), np.asarray(sphere.faces), views)
    assert dropped < np.count_nonzero(~seen)  # the unseen faces next to seen ones stay


def test_a_surface_enclosed_by_another_goes_whole():
    """A small sphere inside a large one: no view sees past the outer surface, and the inner one shares
    no edge with a seen face, so all of it goes; the outer sphere, seen all round, stays."""
    outer = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    mesh = trimesh.util.concatenate([outer, inner])
    views = _ring_of_views(0.0, 8) + _ring_of_views(80.0, 4) + _ring_of_views(-80.0, 4)
    kept, dropped = drop_unseen_faces(mesh, views)
    assert dropped == len(inner.faces)
    assert np.linalg.norm(kept.triangles_center, axis=1).min() > 0.9


def test_a_sheet_seen_only_from_behind_goes():
    """An open sheet facing up: views above it keep it all; views below see only its back, and it goes."""
    sheet = trimesh.creation.box(extents=[2, 2, 0.01]).subdivide_to_size(0.2)
    sheet.update_faces(sheet.face_normals[:, 2] > 0.99)  # its top alone: an open sheet, normals up
    sheet.remove_unreferenced_vertices()
    assert drop_unseen_faces(sheet, _ring_of_views(60.0))[1] == 0
    kept, dropped = drop_unseen_faces(sheet, _ring_of_views(-60.0))
    assert dropped == len(sheet.faces) and len(kept.faces) == 0
