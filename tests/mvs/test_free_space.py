import numpy as np

from recon.mvs.free_space import free_space_counts, in_free_space
from recon.mvs.views import ViewCamera

W, H, F = 64, 48, 60.0
WALL = 10.0  # a wall at z = 10 facing cameras on the plane z = 0, looking along +z
BLOCK = 5.0  # a square block face at z = 5, |x|, |y| <= 0.5
AGREE, MARGIN = 0.01, 0.03


def camera(x: float) -> ViewCamera:
    K = np.array([[F, 0, W / 2], [0, F, H / 2], [0, 0, 1]])
    return ViewCamera(f"v{x}", K, np.eye(3), np.array([-x, 0.0, 0.0]), W, H)


def depth_map(cam: ViewCamera, block: bool) -> np.ndarray:
    """What the camera sees: the wall everywhere, the block in front of it where it stands."""
    depth = np.full((H, W), WALL, np.float32)
    if block:
        cols = (np.arange(W) + 0.5 - W / 2) / F  # ray direction x / z through each pixel centre
        rows = (np.arange(H) + 0.5 - H / 2) / F
        x = -cam.t[0] + cols * BLOCK
        y = rows * BLOCK
        depth[np.ix_(np.abs(y) <= 0.5, np.abs(x) <= 0.5)] = BLOCK
    return depth


def grid(z: float, half: float, n: int) -> np.ndarray:
    u = np.linspace(-half, half, n)
    x, y = np.meshgrid(u, u)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def test_an_object_in_few_photos_is_dropped_and_the_surface_behind_it_kept():
    # the block stands in 2 photos (a car parked for a while); 4 photos see the wall where it stood
    views = [(camera(x), depth_map(camera(x), block=x in (-0.2, 0.2))) for x in (-1.0, -0.6, -0.2, 0.2, 0.6, 1.0)]
    block, wall = grid(BLOCK, 0.4, 9), grid(WALL, 1.5, 15)
    agreeing, seeing_through = free_space_counts(np.vstack([block, wall]), views, AGREE, MARGIN)
    assert (agreeing[:len(block)] == 2).all() and (seeing_through[:len(block)] >= 3).all()
    drop = in_free_space(np.vstack([block, wall]), views, AGREE, MARGIN)
    assert drop[:len(block)].all()
    assert not drop[len(block):].any()  # the wall behind the block is hidden in 2 views, seen in the others


def test_an_object_in_most_photos_is_kept():
    views = [(camera(x), depth_map(camera(x), block=x != 1.0)) for x in (-1.0, -0.6, -0.2, 0.2, 0.6, 1.0)]
    assert not in_free_space(grid(BLOCK, 0.4, 9), views, AGREE, MARGIN).any()


def test_a_point_a_pixel_off_an_edge_is_not_seen_through():
    # points just outside the block's edge in every photo (calibration half a pixel off, a thin pole):
    # the pixel they fall in shows the wall, its neighbour the block
    views = [(camera(x), depth_map(camera(x), block=True)) for x in (-0.2, 0.0, 0.2)]
    edge = np.array([[0.5 + 0.5 * BLOCK / F, y, BLOCK] for y in np.linspace(-0.4, 0.4, 9)])
    agreeing, seeing_through = free_space_counts(edge, views, AGREE, MARGIN)
    assert (agreeing == 0).all()  # the pixel itself shows the wall, 5 units behind
    assert (seeing_through == 0).all()


def test_pixels_without_depth_count_for_neither():
    views = [(camera(x), np.zeros((H, W), np.float32)) for x in (-0.5, 0.0, 0.5)]
    agreeing, seeing_through = free_space_counts(grid(BLOCK, 0.4, 5), views, AGREE, MARGIN)
    assert not agreeing.any() and not seeing_through.any()

