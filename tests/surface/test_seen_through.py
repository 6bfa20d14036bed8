import numpy as np
import trimesh

from recon.mvs.views import ViewCamera
from recon.surface.seen_through import seen_through_faces

W, H, F = 64, 48, 60.0
WALL, FRONT = 10.0, 5.0  # cameras on the plane z = 0 look along +z at a wall at z = 10


def camera(x: float) -> ViewCamera:
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    return ViewCamera(f"v{x}", K, np.eye(3), np.array([-x, 0.0, 0.0]), W, H)


def square(x0: float, x1: float, half_y: float, z: float, n: int = 6) -> trimesh.Trimesh:
    """A square of 2 n^2 faces at depth z facing the cameras."""
    xs, ys = np.meshgrid(np.linspace(x0, x1, n + 1), np.linspace(-half_y, half_y, n + 1))
    vertices = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    return trimesh.Trimesh(vertices, np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]), process=False)


def test_a_face_before_meshed_surface_the_views_saw_goes_and_one_before_a_hole_stays():
    # every photo saw the wall at z = 10 everywhere; the mesh holds the wall only where x <= 0, and two
    # patches of Poisson's surface 5 units in front of it: one before the meshed wall, one before nothing
    wall = square(-5.0, 0.0, 3.0, WALL)
    before_wall = square(-1.5, -1.0, 0.25, FRONT, 2)
    before_hole = square(1.0, 1.5, 0.25, FRONT, 2)
    mesh = trimesh.util.concatenate([wall, before_wall, before_hole])
    views = [(camera(x), np.full((H, W), WALL, np.float32)) for x in (-1.0, -0.5, 0.0, 0.5, 1.0)]
    dropped = seen_through_faces(mesh, views)
    n_wall, n_patch = len(wall.faces), len(before_wall.faces)
    assert not dropped[:n_wall].any()  # the views agree with the wall
    assert dropped[n_wall:n_wall + n_patch].all()  # dropping these shows the wall the photos saw
    assert not dropped[n_wall + n_patch:].any()  # dropping these would open a hole through the model


def test_faces_the_views_agree_with_stay_though_some_see_through_them():
    # a block in front of the wall that three of five photos show; two saw the wall where it stands
    wall, block = square(-5.0, 5.0, 3.0, WALL), square(-0.5, 0.5, 0.5, FRONT, 4)
    mesh = trimesh.util.concatenate([wall, block])
    views = []
    for x in (-1.0, -0.5, 0.0, 0.5, 1.0):
        depth = np.full((H, W), WALL, np.float32)
        if abs(x) < 1.0:
            cols, rows = (np.arange(W) + 0.5 - W / 2) / F, (np.arange(H) + 0.5 - H / 2) / F
            depth[np.ix_(np.abs(rows * FRONT) <= 0.5, np.abs(x + cols * FRONT) <= 0.5)] = FRONT
        views.append((camera(x), depth))
    assert not seen_through_faces(mesh, views).any()
