import numpy as np
import trimesh

from recon.mvs.options import MVSOptions
from recon.mvs.views import ViewCamera
from recon.surface.backdrop import backdrop_faces, backdrop_rim

W, H, F = 64, 48, 60.0
WALL, EDGE = 10.0, 2.0  # cameras on the plane z = 0 look along +z at a wall at z = 10 that ends at x = 2
XS = (-1.0, -0.5, 0.0, 0.5, 1.0)


def camera(x: float) -> ViewCamera:
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    return ViewCamera(f"v{x}", K, np.eye(3), np.array([-x, 0.0, 0.0]), W, H)


def square(x0: float, x1: float, n: int, z: float = WALL, half_y: float = 3.0) -> trimesh.Trimesh:
    """A strip x0 <= x <= x1, |y| <= ``half_y`` of 2 n^2 faces at depth ``z`` (the wall's plane), facing the
    cameras."""
    xs, ys = np.meshgrid(np.linspace(x0, x1, n + 1), np.linspace(-half_y, half_y, n + 1))
    vertices = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    return trimesh.Trimesh(vertices, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]), process=False)


def wall_x(x: float) -> np.ndarray:
    """Where each pixel's ray from the camera at ``x`` meets the wall's plane: its x (H, W)."""
    return np.broadcast_to(x + (np.arange(W) + 0.5 - W / 2) / F * WALL, (H, W))


def view(x: float, everything_background: bool = False):
    """The camera at ``x``, its depth map (the wall where it stands, nothing over the sky beyond its edge)
    and its background reach (the sky; with ``everything_background``, the wall too, unmeasured: a photo
    calls a uniform face that runs out of it, where it measured nothing, background)."""
    sky = wall_x(x) > EDGE
    if everything_background:
        return camera(x), np.zeros((H, W), np.float32), np.ones((H, W), bool)
    return camera(x), np.where(sky, 0.0, WALL).astype(np.float32), sky.copy()


def test_a_fringe_past_the_edge_the_views_show_as_sky_goes_and_the_wall_stays():
    wall, fringe = square(-5.0, EDGE, 14), square(EDGE, EDGE + 1.0, 4)
    dropped = backdrop_faces(trimesh.util.concatenate([wall, fringe]), [view(x) for x in XS])
    assert not dropped[:len(wall.faces)].any()
    assert dropped[len(wall.faces):].all()


def test_a_face_one_view_calls_background_stays_where_more_views_measure_it():
    wall = square(-5.0, EDGE, 14)
    views = [view(x, everything_background=x == 0.0) for x in XS]
    assert not backdrop_faces(wall, views).any()
    # as many calling it background as measuring it: it stays
    views = [view(x, everything_background=x < 0.0) for x in (-1.0, -0.5, 0.5, 1.0)]
    assert not backdrop_faces(wall, views)[np.abs(wall.triangles_center[:, 0]) < 1.0].any()
    # where only two of five measure it and three call it background, it goes
    views = [view(x, everything_background=x <= 0.0) for x in XS]
    seen_by_all = np.abs(wall.triangles_center[:, 0]) < 1.0
    assert backdrop_faces(wall, views)[seen_by_all].all()


def test_a_face_with_mesh_behind_it_stays_though_the_views_show_background_there():
    # an object's uniform side that no photo measured, which every photo calls background: dropping it
    # would show the mesh behind it (the object's far side), not the sky
    side, behind = square(-1.0, 0.4, 4, z=5.0, half_y=1.0), square(-5.0, EDGE, 14)  # the wall behind all of it
    views = [view(x, everything_background=True) for x in XS]
    dropped = backdrop_faces(trimesh.util.concatenate([side, behind]), views)
    assert not dropped[:len(side.faces)].any()
    assert dropped[len(side.faces):].any()  # what of the far side the views see, with nothing behind it, goes


def test_no_background_drops_nothing():
    wall = square(-5.0, EDGE, 6)
    views = [(camera(x), np.full((H, W), WALL, np.float32), np.zeros((H, W), bool)) for x in XS]
    assert not backdrop_faces(wall, views).any()


def test_the_rim_is_the_skys_strip_along_the_horizon():
    # a textured ground, measured, below row 40 of a photo and a flat sky above it: the rim is the sky's
    # rows within the matching window's radius of the horizon (and ground pixels of the sky's shade beside
    # it), not the sky beyond them, not the ground farther down
    horizon, radius = 40, MVSOptions().window_radius
    rng = np.random.default_rng(0)
    image = np.clip(0.4 + 0.15 * rng.standard_normal((120, 160)), 0, 1).astype(np.float32)
    image[:horizon] = 0.8
    depth = np.zeros(image.shape, np.float32)
    depth[horizon:] = 10.0
    rim = backdrop_rim(image, depth, MVSOptions())
    assert rim[horizon - 3:horizon].all()
    assert not rim[:horizon - 1 - radius].any() and not rim[horizon + radius:].any()
