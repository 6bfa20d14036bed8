"""Mesh faces no view sees go (recon.surface.unseen): the hidden underside of an object, a surface
enclosed by another; faces next to a seen face stay."""

import numpy as np
import trimesh

from recon.mvs.views import ViewCamera
from recon.surface.unseen import drop_unseen_faces, face_views
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
    kept, dropped, _ = drop_unseen_faces(sphere, [(v, None) for v in views])
    up = _elevation(sphere) > 0
    assert 0.1 * len(sphere.faces) < dropped < 0.2 * len(sphere.faces)
    assert np.count_nonzero(_elevation(kept) > 0) == np.count_nonzero(up)  # all of the top half stays
    assert _elevation(kept).min() > -48.0  # the bottom cap is gone
    seeing, _, _ = face_views(np.asarray(sphere.vertices), np.asarray(sphere.faces), [(v, None) for v in views])
    assert dropped < np.count_nonzero(seeing == 0)  # the unseen faces next to seen ones stay


def test_a_surface_enclosed_by_another_goes_whole():
    """A small sphere inside a large one: no view sees past the outer surface, and the inner one shares
    no edge with a seen face, so all of it goes; the outer sphere, seen all round, stays."""
    outer = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    inner = trimesh.creation.icosphere(subdivisions=3, radius=0.4)
    mesh = trimesh.util.concatenate([outer, inner])
    views = _ring_of_views(0.0, 8) + _ring_of_views(80.0, 4) + _ring_of_views(-80.0, 4)
    kept, dropped, _ = drop_unseen_faces(mesh, [(v, None) for v in views])
    assert dropped == len(inner.faces)
    assert np.linalg.norm(kept.triangles_center, axis=1).min() > 0.9


def test_a_sheet_seen_only_from_behind_goes():
    """An open sheet facing up: views above it keep it all; views below see only its back, and it goes."""
    sheet = trimesh.creation.box(extents=[2, 2, 0.01]).subdivide_to_size(0.2)
    sheet.update_faces(sheet.face_normals[:, 2] > 0.99)  # its top alone: an open sheet, normals up
    sheet.remove_unreferenced_vertices()
    assert drop_unseen_faces(sheet, [(v, None) for v in _ring_of_views(60.0)])[1] == 0
    kept, dropped, _ = drop_unseen_faces(sheet, [(v, None) for v in _ring_of_views(-60.0)])
    assert dropped == len(sheet.faces) and len(kept.faces) == 0


def test_faces_the_views_see_without_a_depth_go_unless_they_fill_a_hole_in_the_depth_maps():
    """Ground with a patch no depth map measures (a window pane, a road marking running to the ground's
    edge: depths on three sides of it) and a curtain rising from its far edge into the empty sky, which
    four views see and none measures: the curtain goes, the patch and the ground stay. Seen by fewer views
    than ``unmeasured_views``, the curtain stays."""
    from recon.surface.raycast import render_ids, scene_of

    ground = trimesh.creation.box(extents=[4, 4, 0.01]).subdivide_to_size(0.2)
    ground.update_faces(ground.face_normals[:, 2] > 0.99)
    curtain = trimesh.Trimesh([[-2, 2, 0], [2, 2, 0], [2, 2, 1.5], [-2, 2, 1.5]], [[0, 1, 2], [0, 2, 3]])
    curtain = curtain.subdivide_to_size(0.2)  # facing -y, towards the views
    mesh = trimesh.util.concatenate([ground, curtain])
    is_curtain = np.arange(len(mesh.faces)) >= len(ground.faces)
    centres = mesh.triangles_center
    is_patch = ~is_curtain & (np.abs(centres[:, :2]).max(axis=1) < 0.4)
    # a strip from the patch to the ground's near edge, like a road marking: no depth beyond its end
    is_patch |= ~is_curtain & (np.abs(centres[:, 0]) < 0.3) & (centres[:, 1] < 0)
    views = []
    for k, x in enumerate((-1.5, -0.5, 0.5, 1.5)):
        R, t = look_at(np.array([x, -5.0, 2.5]), np.array([0.0, 0.5, 0.3]))
        views.append(ViewCamera(f"v{k}.jpg", np.array([[140, 0, 80], [0, 140, 60], [0, 0, 1.0]]), R, t, 160, 120))
    scene = scene_of(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    maps = []
    for view in views:
        hit = render_ids(scene, view, view.width, view.height)
        unmeasured = (hit["face"] < 0) | is_curtain[hit["face"]] | is_patch[hit["face"]]
        maps.append((view, np.where(unmeasured, 0.0, hit["depth"]).astype(np.float32)))
    kept, unseen, unmeasured = drop_unseen_faces(mesh, maps, unmeasured_views=3)
    seeing, measuring, _ = face_views(np.asarray(mesh.vertices), np.asarray(mesh.faces), maps)
    # the curtain, less faces on its foot whose centres fall on a pixel of the ground beside it
    condemned = is_curtain & (seeing >= 3) & (measuring == 0)
    assert condemned.sum() > 0.9 * is_curtain.sum()
    edge_row = is_patch & (centres[:, 1] < -1.9)  # on the ground's very edge only two sides hold depths
    assert unseen == 0 and condemned.sum() <= unmeasured <= condemned.sum() + edge_row.sum()
    c = kept.triangles_center
    kept_patch = (np.abs(c[:, :2]).max(axis=1) < 0.4) | ((np.abs(c[:, 0]) < 0.3) & (c[:, 1] < 0))
    assert np.count_nonzero(kept_patch & (np.abs(c[:, 2]) < 0.01) & (c[:, 1] > -1.9)) == (is_patch & ~edge_row).sum()
    two = maps[1:3]  # the curtain seen by two views: none of it goes for want of a depth
    assert drop_unseen_faces(mesh, two, unmeasured_views=3)[2] == 0
