"""Depths carried from a surface's edge onto the sky beside it are dropped (recon.mvs.background), and
only there."""

from __future__ import annotations

import numpy as np

from recon.mvs.background import clear_background
from recon.mvs.options import MVSOptions
from recon.mvs.patchmatch import untextured

W, H = 160, 120
RADIUS, SHADE = MVSOptions().window_radius, MVSOptions().sigma_color / 2
HORIZON = 40  # rows above it: sky
SKY = 0.8
#: the sky's rows nearest the edge that ripple
FRINGE = 3


def ground_photo(ringing: float = 0.012) -> np.ndarray:
    """A textured ground below :data:`HORIZON` and a flat sky above it, whose :data:`FRINGE` rows nearest
    the edge ripple by ``ringing``, halving row by row (as JPEG rings around an edge)."""
    rng = np.random.default_rng(0)
    image = 0.4 + 0.15 * rng.standard_normal((H, W))
    image = (image + np.roll(image, 1, 0) + np.roll(image, 1, 1)) / 3
    image[:HORIZON] = SKY
    for k in range(FRINGE):
        image[HORIZON - 1 - k] += ringing / 2**k * np.where((np.arange(W) // 2) % 2 == 0, 1.0, -1.0)
    return np.clip(image, 0, 1).astype(np.float32)


def maps(fringe_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Depth and normal maps holding the ground below the horizon and its plane carried ``fringe_rows``
    rows above it."""
    depth = np.zeros((H, W), np.float32)
    depth[HORIZON - fringe_rows:] = np.linspace(20.0, 4.0, H - HORIZON + fringe_rows, dtype=np.float32)[:, None]
    normal = np.zeros((H, W, 3), np.float32)
    normal[depth > 0] = (0.0, -0.9, -0.44)
    return depth, normal


def test_the_ground_carried_onto_the_sky_goes_and_the_ground_stays():
    image = ground_photo()
    blank = untextured(image, MVSOptions())
    assert not blank[HORIZON - 2].any(), \
        "a rippling sky row passes the filter's texture test: what this module is for"
    depth, normal = maps(FRINGE)
    ground = depth[HORIZON:].copy()
    cleared = clear_background(image, blank, depth, normal, MVSOptions())
    assert cleared == FRINGE * W
    assert not depth[:HORIZON].any() and not normal[:HORIZON].any()
    assert np.array_equal(depth[HORIZON:], ground)


def test_a_flat_face_inside_the_photo_keeps_the_depths_at_its_edge():
    """A box face in flat paint is no backdrop: the planar fill gives it the plane of its rim."""
    image = ground_photo(ringing=0.0)
    image[:HORIZON] = ground_photo()[HORIZON:2 * HORIZON]  # textured above too: the flat band is enclosed
    image[50:90, 40:120] = SKY
    blank = untextured(image, MVSOptions())
    depth, normal = maps(HORIZON)
    depth[55:85, 45:115] = 0
    before = depth.copy()
    assert clear_background(image, blank, depth, normal, MVSOptions()) == 0
    assert np.array_equal(depth, before)


def test_a_small_flat_patch_at_the_border_is_not_a_backdrop():
    image = ground_photo(ringing=0.0)
    image[:HORIZON] = ground_photo()[HORIZON:2 * HORIZON]
    image[:8, :12] = SKY  # 96 px, half of 1 % of the photo
    blank = untextured(image, MVSOptions())
    depth, normal = maps(HORIZON)
    assert clear_background(image, blank, depth, normal, MVSOptions()) == 0


def test_the_surface_in_another_shade_beside_the_sky_keeps_its_depth():
    """Within the window's radius of the sky, a pixel of the ground's shade keeps its depth."""
    image = ground_photo(ringing=0.0)
    blank = untextured(image, MVSOptions())
    depth, normal = maps(0)
    near = depth[HORIZON:HORIZON + RADIUS]
    near_sky = np.abs(image[HORIZON:HORIZON + RADIUS] - SKY) <= SHADE
    cleared = clear_background(image, blank, depth, normal, MVSOptions())
    assert cleared == np.count_nonzero(near_sky)
    assert cleared < 0.05 * near.size
    assert np.count_nonzero(depth[HORIZON:HORIZON + RADIUS]) == near.size - cleared
