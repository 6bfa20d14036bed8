"""The visibility-based Delaunay surface (recon.surface.delaunay) on a sphere seen from all around, with
exact depth maps: the surface passes through the points, and stray points in the free space between the
cameras and the sphere are cut away."""

import numpy as np
import pytest
from surface_scene import sphere_points

from recon.mvs.views import ViewCamera
from recon.surface.delaunay import delaunay_mesh, lines_of_sight, thin
from recon.surface.options import MeshOptions

WIDTH, HEIGHT, FOCAL = 160, 120, 150.0


def _look_at(name: str, centre: np.ndarray) -> ViewCamera:
    z = -centre / np.linalg.norm(centre)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    K = np.array([[FOCAL, 0, WIDTH / 2], [0, FOCAL, HEIGHT / 2], [0, 0, 1.0]])
    return ViewCamera(name, K, R, -R @ centre, WIDTH, HEIGHT)


def _unit_sphere_depth(cam: ViewCamera) -> np.ndarray:
    """Each pixel's depth (camera z) where its ray meets the unit sphere at the origin; 0 where it misses."""
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    rays = np.stack([(u - cam.K[0, 2]) / FOCAL, (v - cam.K[1, 2]) / FOCAL, np.ones_like(u)], -1)  # z = 1
    world = rays @ cam.R  # directions in the world, camera z still 1
    centre = -cam.R.T @ cam.t
    b = world @ centre
    a = np.einsum("hwi,hwi->hw", world, world)
    disc = b * b - a * (centre @ centre - 1.0)
    with np.errstate(invalid="ignore"):
        s = (-b - np.sqrt(disc)) / a
    return np.where(disc > 0, s, 0.0).astype(np.float32)


@pytest.fixture(scope="module")
def sphere_views():
    views = []
    for i, az in enumerate(np.linspace(0, 2 * np.pi, 12, endpoint=False)):
        elevation = 0.6 * (-1) ** i
        centre = 4.0 * np.array([np.cos(az) * np.cos(elevation), np.sin(az) * np.cos(elevation), np.sin(elevation)])
        cam = _look_at(f"v{i}", centre)
        views.append((cam, _unit_sphere_depth(cam)))
    return views


def test_every_point_has_the_lines_of_sight_of_the_views_that_see_it(sphere_views):
    points = sphere_points(2000)
    ray_point, ray_view, centres = lines_of_sight(points, sphere_views, agree=0.01)
    assert np.allclose(np.linalg.norm(centres, axis=1), 4.0)
    # a view sees a point of the sphere when the point faces it (and lies in its frame: all do here);
    # at grazing angles a pixel's depth varies by more than the 1 % agreement across the pixel
    sight = centres[None] - points[:, None]
    cosine = np.einsum("pi,pvi->pv", points, sight) / np.linalg.norm(sight, axis=2)
    seen = np.zeros(cosine.shape, bool)
    seen[ray_point, ray_view] = True
    assert seen[cosine > 0.5].mean() > 0.98
    assert not seen[cosine < -0.02].any()


def test_the_surface_passes_through_the_points_and_cuts_strays_away(sphere_views):
    """Strays in front of the sphere that one view's depth map holds (something in one photo only): the
    lines of sight of the other views to the sphere behind them carve them away."""
    rng = np.random.default_rng(0)
    cam, depth = sphere_views[0]
    toward = -cam.R.T @ cam.t / 4.0  # the unit direction to the first camera
    strays = toward + 0.2 * rng.normal(size=(40, 3))
    strays *= (1.3 + 0.5 * rng.random((40, 1))) / np.linalg.norm(strays, axis=1, keepdims=True)
    seen = depth.copy()
    xyz = strays @ cam.R.T + cam.t
    col, row = (xyz[:, :2] / xyz[:, 2:] * FOCAL + [WIDTH / 2, HEIGHT / 2]).astype(int).T
    seen[row, col] = xyz[:, 2]
    views = [(cam, seen), *sphere_views[1:]]
    points = np.vstack([sphere_points(6000), strays])
    assert np.isin(np.arange(6000, 6040), lines_of_sight(points, views, 0.01)[0]).sum() >= 30  # (some share a pixel)
    mesh = delaunay_mesh(points, None, views, MeshOptions(depth=7))  # cells of 2 / 256
    radius = np.linalg.norm(mesh.vertices, axis=1)
    assert np.abs(radius - 1.0).max() < 1e-9  # no stray is a vertex of the surface
    assert mesh.area == pytest.approx(4 * np.pi, rel=0.03)
    # facing outwards: from the inside tetrahedra towards the cameras
    assert np.mean(np.einsum("fi,fi->f", mesh.face_normals, mesh.triangles_center) > 0) > 0.99


def test_thinning_keeps_one_point_per_cell():
    points = np.random.default_rng(1).random((5000, 3))
    kept = thin(points, 0.25)
    assert len(kept) == 64
    cells = np.floor(points[kept] / 0.25).astype(int)
    assert len(np.unique(cells, axis=0)) == 64


def test_a_flat_cloud_is_refused_with_a_reason(sphere_views):
    flat = np.column_stack([np.random.default_rng(2).random((500, 2)), np.zeros(500)])
    with pytest.raises(ValueError, match="do not span a volume"):
        delaunay_mesh(flat, None, sphere_views)
