"""Untextured regions of a depth map filled with the plane of the depths around them (recon.mvs.planar_fill),
and only where that plane is unambiguous."""

from __future__ import annotations

import numpy as np
import pytest

from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import untextured
from recon.mvs.planar_fill import fill_untextured

W, H = 160, 120
K = np.array([[150.0, 0.0, W / 2], [0.0, 150.0, H / 2], [0.0, 0.0, 1.0]])
KINV = np.linalg.inv(K)
U, V = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)


def plane(a: float, b: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Depth and normal maps of the plane whose inverse depth is a u + b v + c at pixel (u, v)."""
    n = K.T @ np.array([a, b, c])
    n = -n / np.linalg.norm(n)  # facing the camera (n . ray < 0 where the depth is positive)
    return (1.0 / (a * U + b * V + c)).astype(np.float32), np.broadcast_to(n, (H, W, 3)).astype(np.float32)


def photo(*flat: tuple[slice, slice, float]) -> np.ndarray:
    """A textured grey photo with the given (rows, cols, shade) rectangles painted flat."""
    rng = np.random.default_rng(0)
    image = 0.5 + 0.2 * rng.standard_normal((H, W))
    image = np.clip((image + np.roll(image, 1, 0) + np.roll(image, 1, 1)) / 3, 0, 1)
    for rows, cols, shade in flat:
        image[rows, cols] = shade
    return image.astype(np.float32)


def measured(image: np.ndarray, depth: np.ndarray, normal: np.ndarray):
    """What the filter leaves: no depth where the photo is untextured."""
    blank = untextured(image, MVSOptions())
    return blank, np.where(blank, 0, depth).astype(np.float32), np.where(blank[..., None], 0, normal).astype(np.float32)


BOX = (slice(40, 80), slice(50, 110))


def test_an_untextured_face_takes_the_plane_of_its_rim():
    true_depth, true_normal = plane(0.0004, 0.0006, 0.15)
    image = photo((*BOX, 0.4))
    blank, depth, normal = measured(image, true_depth, true_normal)
    assert blank[BOX].mean() > 0.6 and not np.any(depth[BOX][8:-8, 8:-8])
    filled = fill_untextured(image, blank, depth, normal, KINV, 0.01)
    assert filled > 0.9 * blank[BOX].sum()
    inside = depth[BOX] > 0
    assert inside.mean() > 0.9
    assert np.max(np.abs(depth[BOX][inside] / true_depth[BOX][inside] - 1)) < 1e-4
    assert np.allclose(normal[BOX][inside], true_normal[BOX][inside], atol=1e-3)


def test_a_region_running_out_of_the_frame_is_left_alone():
    """Sky, a black background: what lies past the border is unknown."""
    true_depth, true_normal = plane(0.0004, 0.0006, 0.15)
    image = photo((slice(0, 60), slice(50, 110), 0.4))
    blank, depth, normal = measured(image, true_depth, true_normal)
    assert fill_untextured(image, blank, depth, normal, KINV, 0.01) == 0


def test_a_region_between_two_surfaces_is_left_alone():
    """The rim's depths lie on two planes (a step behind the face's middle): no one plane fits them."""
    near, normal_near = plane(0.0004, 0.0006, 0.15)
    far, _ = plane(0.0004, 0.0006, 0.13)
    true_depth = np.where(U < 80, near, far)
    image = photo((*BOX, 0.4))
    blank, depth, normal = measured(image, true_depth, normal_near)
    assert fill_untextured(image, blank, depth, normal, KINV, 0.01) == 0


def test_a_planar_rim_seen_edge_on_is_left_alone():
    """An untextured ball's limb is a planar circle, but the surface there is seen edge-on: the rim's own
    normals lie across the rays."""
    true_depth, _ = plane(0.0, 0.0, 0.2)
    rays = np.stack([U, V, np.ones_like(U)], axis=-1) @ KINV.T
    edge_on = np.cross(rays, [0.0, 0.0, 1.0])
    edge_on /= np.maximum(np.linalg.norm(edge_on, axis=-1, keepdims=True), 1e-9)
    image = photo((*BOX, 0.4))
    blank, depth, normal = measured(image, true_depth, edge_on.astype(np.float32))
    assert fill_untextured(image, blank, depth, normal, KINV, 0.01) == 0
    blank, depth, normal = measured(image, true_depth, plane(0.0, 0.0, 0.2)[1])
    assert fill_untextured(image, blank, depth, normal, KINV, 0.01) > 0  # the normals alone decided


def test_a_face_takes_its_plane_whatever_the_normals_of_the_faces_around_it():
    """A box face's rim is its edges, where the depths and normals are those of the faces around it, seen
    from the front (here at 70 degrees from the face's own normal): the face still gets its plane."""
    true_depth, true_normal = plane(0.0, 0.0, 0.2)
    turned = np.zeros_like(true_normal)
    turned[..., 0], turned[..., 2] = np.sin(np.radians(70)), -np.cos(np.radians(70))
    image = photo((*BOX, 0.4))
    blank, depth, normal = measured(image, true_depth, turned.astype(np.float32))
    assert fill_untextured(image, blank, depth, normal, KINV, 0.01) > 0.9 * blank[BOX].sum()
    inside = depth[BOX] > 0
    assert inside.mean() > 0.9
    assert np.max(np.abs(depth[BOX][inside] / true_depth[BOX][inside] - 1)) < 1e-4


@pytest.mark.parametrize("shades", [(0.4, 0.55), (0.4, 0.4)])
def test_two_faces_meeting_at_an_edge_each_take_their_own_plane_when_their_shades_differ(shades):
    """A box's two faces in one paint, lit differently: one region each. In one shade they are one region
    whose rim holds two planes, and nothing is filled."""
    crease = 80.0
    left_depth, left_normal = plane(0.0008, 0.0004, 0.1)
    right_depth, right_normal = plane(-0.0004, 0.0004, 0.1 + 0.0012 * crease)  # the same depth at the crease
    right = U > crease
    true_depth = np.where(right, right_depth, left_depth)
    true_normal = np.where(right[..., None], right_normal, left_normal)
    image = photo((BOX[0], slice(50, 80), shades[0]), (BOX[0], slice(80, 110), shades[1]))
    blank, depth, normal = measured(image, true_depth, true_normal)
    filled = fill_untextured(image, blank, depth, normal, KINV, 0.01)
    if shades[0] == shades[1]:
        assert filled == 0
        return
    for cols in (slice(52, 78), slice(82, 108)):
        face = (BOX[0], cols)
        inside = depth[face] > 0
        assert inside.mean() > 0.8, cols
        assert np.max(np.abs(depth[face][inside] / true_depth[face][inside] - 1)) < 1e-3, cols
