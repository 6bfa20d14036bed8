"""A depth its sources match no better than they match the plane at infinity is dropped (recon.mvs.at_infinity):
the sky goes, a surface with parallax stays."""

from __future__ import annotations

import numpy as np
import pytest
from plane_views import FOCAL, H, W, camera, texture

from recon.mvs.at_infinity import drop_at_infinity, matched_at_infinity
from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import Camera, State, checked, photometric_costs

HORIZON = 50  # rows above it show the sky, the rest a textured wall
#: camera centres: the reference and its sources, beside and above it
CENTRES = ((0.0, 0.0), (0.3, 0.0), (-0.3, 0.0), (0.0, 0.25))


def render(cam: Camera, wall: float) -> np.ndarray:
    """Photo of a wall at depth ``wall`` below the horizon row and, above it, a sky at infinity whose shade
    varies with the ray's elevation (bands of cloud): every camera sees the same sky along the same ray."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    dx, dy = (u - W / 2) / FOCAL, (v - H / 2) / FOCAL
    cx, cy = -cam.t[0], -cam.t[1]
    sky = 0.6 + 0.08 * np.sin(30 * dy) + 0.3 * dy
    # the wall's top edge is the horizon row as the reference sees it
    on_wall = cy + wall * dy >= wall * (HORIZON - H / 2) / FOCAL
    return np.where(on_wall, texture(cx + wall * dx, cy + wall * dy, 3), sky).astype(np.float32)


def view_and_state(wall: float, sky_depth: float):
    images = [render(camera(*c), wall) for c in CENTRES]
    cams = [camera(*c) for c in CENTRES]
    depth = np.full((H, W), wall, np.float32)
    depth[:HORIZON] = sky_depth  # a depth PatchMatch gave the sky: any far one matches as well
    normal = np.zeros((H, W, 3), np.float32)
    normal[..., 2] = -1
    views = np.full((H, W), (1 << (len(CENTRES) - 1)) - 1, np.int64)
    source_depths = [np.full((H, W), wall, np.float32) for _ in CENTRES[1:]]
    view = checked(images[0], images[1:], cams[0], cams[1:], source_depths)
    # (the costs the filter keeps each depth for)
    return view, photometric_costs(view, State(depth, normal, np.zeros((H, W), np.float32), views), MVSOptions())


@pytest.mark.parametrize("sky_depth", [20.0, 200.0])
def test_the_sky_matched_at_some_far_depth_goes_and_the_wall_stays(sky_depth):
    view, state = view_and_state(4.0, sky_depth)
    found = matched_at_infinity(view, state, MVSOptions())
    inner = np.s_[8:-8, 8:-8]  # (windows that reach over the photo's border match less well either way)
    sky = np.zeros((H, W), bool)
    sky[: HORIZON - 6] = True
    wall = np.zeros((H, W), bool)
    wall[HORIZON + 6:] = True
    assert found[inner][sky[inner]].mean() >= 0.95
    assert found[inner][wall[inner]].mean() <= 0.01


def test_a_far_wall_with_a_pixel_of_parallax_keeps_its_depth():
    """At 40 units the sources 0.3 apart see the wall 1.1 px from where the sky would be: enough."""
    view, state = view_and_state(40.0, 40.0)
    found = matched_at_infinity(view, state, MVSOptions())
    wall = np.zeros((H, W), bool)
    wall[HORIZON + 6:-8, 8:-8] = True
    assert found[wall].mean() <= 0.05


def test_dropping_zeroes_the_depth_and_normal_of_what_matched_at_infinity_only():
    view, state = view_and_state(4.0, 20.0)
    found = matched_at_infinity(view, state, MVSOptions())
    before = state.depth.copy()
    assert drop_at_infinity(view, state, MVSOptions()) == found.sum() > 0
    assert not state.depth[found].any() and not state.normal[found].any()
    np.testing.assert_array_equal(state.depth[~found], before[~found])
