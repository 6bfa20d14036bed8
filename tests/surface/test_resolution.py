"""How finely the photos show a mesh (recon.surface.resolution): each face's area in pixels in the view
that shows it largest, which sets how far mesh.max_faces_per_pixel decimates."""

import numpy as np
import trimesh

from recon.mvs.views import ViewCamera
from recon.surface.resolution import best_view_pixels, resolved_faces

W, H, F = 64, 48, 60.0


def camera(z: float) -> ViewCamera:
    """A camera at (0, 0, z) looking along +z."""
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    return ViewCamera(f"z{z}", K, np.eye(3), np.array([0.0, 0.0, -z]), W, H)


def square(half: float, z: float, n: int = 4, towards_cameras: bool = True) -> trimesh.Trimesh:
    """A square of 2 n^2 faces at depth z, turned towards the cameras (-z) or away."""
    xs, ys = np.meshgrid(np.linspace(-half, half, n + 1), np.linspace(-half, half, n + 1))
    vertices = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], axis=1)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]
    a, b, c, d = i.ravel(), i.ravel() + 1, i.ravel() + n + 1, i.ravel() + n + 2
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    return trimesh.Trimesh(vertices, faces if towards_cameras else faces[:, ::-1], process=False)


def test_each_face_counts_its_area_in_the_view_that_shows_it_largest():
    mesh = square(1.0, 10.0)
    far = best_view_pixels(mesh, [camera(0.0)])
    assert np.isclose(far.sum(), (2 * F / 10.0) ** 2)  # 12 x 12 px at depth 10
    near = best_view_pixels(mesh, [camera(0.0), camera(5.0)])
    assert np.isclose(near.sum(), (2 * F / 5.0) ** 2)  # 24 x 24 px from the camera at depth 5
    assert np.allclose(near, near[0])  # equal faces, equal areas
    assert resolved_faces(mesh, [camera(0.0), camera(5.0)], 0.25) == 144


def test_faces_no_view_sees_count_nothing():
    assert not best_view_pixels(square(1.0, 10.0, towards_cameras=False), [camera(0.0)]).any()  # turned away
    assert not best_view_pixels(square(1.0, -10.0), [camera(0.0)]).any()  # behind the camera
