"""The PatchMatch kernels on an exactly known scene: a textured slanted plane seen by a few cameras."""

import dataclasses

import cv2
import numba
import numpy as np
import pytest

from recon.mvs import patchmatch as pm
from recon.mvs.options import MVSOptions

WIDTH, HEIGHT = 96, 72
OPTIONS = MVSOptions(iterations=4)
THREE = dataclasses.replace(OPTIONS, top_k=3)  # the mean over three sources, one or two of which look elsewhere
# the filter's confirmation by the sources' depth maps alone: on this smooth texture a plane 5 % off costs
# under filter_unconfirmed_cost at about half its pixels (its shift in the sources is under a pixel)
CONFIRMED, THREE_CONFIRMED = (dataclasses.replace(o, filter_unconfirmed_cost=0.0) for o in (OPTIONS, THREE))
SKY = 0.75
CENTRES = [(0.0, 0.0, 0.0), (0.3, 0.0, 0.0), (-0.3, 0.05, 0.0), (0.0, 0.25, 0.05)]


def _plane_scene(tilt_deg: float = 25.0, depth: float = 2.0, seed: int = 0, uniform_from: float | None = None):
    """Images (float32 [0, 1]), cameras and true depth maps of views of the plane through (0, 0, depth)
    whose normal is tilted by ``tilt_deg`` about the y axis; view 0 is the reference. With
    ``uniform_from``, the plane is one flat light grey (as a sky is) beyond that coordinate along its
    tilted x axis, and darker than it elsewhere."""
    rng = np.random.default_rng(seed)
    texture = cv2.resize(rng.random((48, 48)).astype(np.float32), (480, 480), interpolation=cv2.INTER_CUBIC)
    if uniform_from is not None:
        texture = 0.6 * texture
        texture[:, int((uniform_from + 1.0) * 240):] = SKY
    t = np.radians(tilt_deg)
    normal = np.array([np.sin(t), 0.0, -np.cos(t)])
    e1 = np.array([np.cos(t), 0.0, np.sin(t)])
    e2 = np.cross(normal, e1)
    origin = np.array([0.0, 0.0, depth])
    f = 1.2 * WIDTH
    K = np.array([[f, 0, WIDTH / 2], [0, f, HEIGHT / 2], [0, 0, 1]])
    u, v = np.meshgrid(np.arange(WIDTH) + 0.5, np.arange(HEIGHT) + 0.5)
    rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
    images, cams, depths = [], [], []
    for centre in CENTRES:
        centre = np.asarray(centre)
        s = (normal @ (origin - centre)) / (rays @ normal)
        X = centre + s[..., None] * rays  # R = I, so camera rays are world rays
        a, b = (X - origin) @ e1, (X - origin) @ e2
        map_x = ((a + 1.0) * 240).astype(np.float32)
        map_y = ((b + 1.0) * 240).astype(np.float32)
        images.append(cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT))
        cams.append(pm.Camera(K, np.eye(3), -centre))
        depths.append((X[..., 2] - centre[2]).astype(np.float32))
    normal_cam = np.broadcast_to(normal.astype(np.float32), (HEIGHT, WIDTH, 3)).copy()
    return images, cams, depths, normal_cam


@pytest.fixture(scope="module")
def plane():
    return _plane_scene()


def _state(depth, normal):
    every_source = (1 << (len(CENTRES) - 1)) - 1
    return pm.State(depth.copy(), normal.copy(), np.zeros_like(depth), np.full(depth.shape, every_source, np.int64))


def test_window_grid_is_symmetric():
    start, step, count = pm.window_grid(5, 2)
    ticks = start + step * np.arange(count)
    np.testing.assert_array_equal(ticks, [-5, -3, -1, 1, 3, 5])
    start, step, count = pm.window_grid(3, 1)
    assert (start, step, count) == (-3, 1, 7)


def test_propagation_regions_read_the_other_colour():
    for region, count in zip(pm.REGION_OFFSETS, pm.REGION_COUNTS):
        dx, dy = region[:count, 0], region[:count, 1]
        assert np.all((dx + dy) % 2 == 1)
    assert len({tuple(r[0]) for r in pm.REGION_OFFSETS}) == 8


def test_pyramid_levels_keep_the_coarsest_level_large_enough():
    options = MVSOptions(pyramid_levels=4, pyramid_min_size=160)
    assert pm.pyramid_levels((1024, 1536), options) == 4
    assert pm.pyramid_levels((480, 640), options) == 3
    assert pm.pyramid_levels((72, 96), options) == 1


def test_cost_is_lowest_at_the_true_plane(plane):
    images, cams, depths, normal = plane
    level = pm.make_level(images[0], images[1:], cams[0], cams[1:])
    inner = (slice(8, -8), slice(8, -8))
    costs = {}
    for scale in (1.0, 0.97, 1.03):
        state = _state(depths[0] * scale, normal)
        pm.evaluate_state(level, state, OPTIONS, pm.ALL_VIEWS)
        costs[scale] = float(np.median(state.cost[inner]))
    # mvs.sigma_color 0.1 puts a window's weight on fewer pixels, so the warped views' resampling noise
    # weighs more at the true plane (median 0.062; 0.026 at 0.2) and the wrong planes cost more (0.37; 0.20)
    assert costs[1.0] < 0.1
    assert costs[0.97] > costs[1.0] + 0.1 and costs[1.03] > costs[1.0] + 0.1


def test_photometric_depth_recovers_a_slanted_plane(plane):
    images, cams, depths, normal = plane
    state = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.0, 4.0), OPTIONS, seed=3)
    inner = (slice(6, -6), slice(6, -6))
    error = np.abs(state.depth - depths[0])[inner] / depths[0][inner]
    assert (error < 0.01).mean() > 0.9
    cos = np.sum(state.normal[inner] * normal[inner], axis=-1)
    assert np.median(np.degrees(np.arccos(np.clip(cos, -1, 1)))) < 5.0


def test_results_do_not_depend_on_threads(plane):
    images, cams, _, _ = plane
    options = dataclasses.replace(OPTIONS, iterations=2)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.0, 4.0), options, seed=7)
        numba.set_num_threads(max(2, threads))
        two = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.0, 4.0), options, seed=7)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one.depth, two.depth)
    np.testing.assert_array_equal(one.normal, two.normal)
    other = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.0, 4.0), options, seed=8)
    assert not np.array_equal(one.depth, other.depth)


def _agreeing(depths, normal, cams, depth_scale=1.0, allowance=5.0):
    g = pm.make_level(depths[0], depths[1:], cams[0], cams[1:]).geometry
    src_depth, dims = pm.stack_images(depths[1:])
    return pm.consistent_views(depths[0] * depth_scale, normal, g.kinv, g.A, g.b, src_depth, dims, g.M, g.c,
                               1.0, 0.01, allowance)


def test_consistent_views_counts_agreeing_sources(plane):
    _, cams, depths, normal = plane
    count = _agreeing(depths, normal, cams)
    assert count.max() == 3 and (count[25:-25, 25:-25] == 3).all()
    assert _agreeing(depths, normal, cams, depth_scale=1.05).max() == 0
    assert _agreeing(depths, normal, cams, depth_scale=1.02).max() == 0  # seen at 27 degrees: 1.8 % across it


def test_sources_agree_across_a_plane_seen_at_a_grazing_angle():
    """A plane at 70 degrees: the sources' exact depths, read at their pixel centres, differ from the
    projected depth by more than 1 % along their rays though they lie on the plane. Measured across the
    plane they agree; a plain depth difference (allowance 1) rejects most of them."""
    _, cams, depths, normal = _plane_scene(tilt_deg=70.0)
    inner = (slice(10, -10), slice(10, -10))
    plain = _agreeing(depths, normal, cams, allowance=1.0)[inner]
    across = _agreeing(depths, normal, cams)[inner]
    assert (plain == 3).mean() < 0.3
    assert (across == 3).mean() > 0.6
    assert (across >= plain).all()


def test_geometric_term_penalises_disagreeing_depth_maps(plane):
    images, cams, depths, normal = plane
    level = pm.make_level(images[0], images[1:], cams[0], cams[1:])
    inner = (slice(25, -25), slice(25, -25))
    results = []
    for scale in (1.0, 1.1):
        src_depth, _ = pm.stack_images([d * scale for d in depths[1:]])
        state = _state(depths[0], normal)
        pm.evaluate_state(level, state, OPTIONS, pm.ALL_VIEWS, src_depth)
        results.append(float(np.median(state.cost[inner])))
    photometric = _state(depths[0], normal)
    pm.evaluate_state(level, photometric, OPTIONS, pm.ALL_VIEWS)
    assert results[0] == pytest.approx(float(np.median(photometric.cost[inner])), abs=0.02)
    assert results[1] > results[0] + OPTIONS.geometric_weight  # errors of several pixels, capped at 3


def _costed(view, depth, normal, options=OPTIONS):
    """The state of the planes (depth, normal) with their photometric costs, as the filter takes it."""
    return pm.photometric_costs(view, _state(depth, normal), options)


def _checked(images, cams, depth_maps):
    """The reference (images[0]) with its sources and their depth maps, as geometric_depth and
    filter_depth take them."""
    return pm.checked(images[0], images[1:], cams[0], cams[1:], depth_maps)


def test_filter_keeps_confirmed_pixels_only(plane):
    images, cams, depths, normal = plane
    view = _checked(images, cams, depths[1:])
    kept = pm.filter_depth(view, _costed(view, depths[0], normal), CONFIRMED)
    assert (kept.depth[25:-25, 25:-25] > 0).all()
    assert ((kept.depth == 0) == (kept.normal == 0).all(axis=-1)).all()
    dropped = pm.filter_depth(view, _costed(view, depths[0] * 1.05, normal), CONFIRMED)
    assert not dropped.depth.any()


def test_the_geometric_pass_leaves_the_photometric_costs_the_filter_tests(plane):
    """geometric_depth subtracts the reprojection term from its costs rather than matching every window
    again for the filter: the result must equal a photometric evaluation of its final planes over the
    same view masks, where sources see the plane, miss it (the image borders) or disagree with it."""
    images, cams, depths, normal = plane
    options = dataclasses.replace(OPTIONS, top_k=2)  # masks of 2 of the 3 sources
    rng = np.random.default_rng(1)
    start = (depths[0] * rng.uniform(0.9, 1.1, depths[0].shape)).astype(np.float32)
    sources = [d * 1.02 for d in depths[1:]]  # reprojection errors of a few pixels, some capped
    view = _checked(images, cams, sources)
    state = pm.geometric_depth(view, _state(start, normal), (1.0, 4.0), options, seed=0)
    assert set(np.unique(state.views)) <= {0b011, 0b101, 0b110}
    level = view.level
    photometric = pm.State(state.depth, state.normal, np.zeros_like(state.cost), state.views.copy())
    pm.evaluate_state(level, photometric, options, pm.KEEP_VIEWS)
    np.testing.assert_allclose(state.cost, photometric.cost, atol=1e-4)
    combined = pm.State(state.depth, state.normal, np.zeros_like(state.cost), state.views.copy())
    pm.evaluate_state(level, combined, options, pm.KEEP_VIEWS, view.src_depth)
    assert np.median(combined.cost - photometric.cost) > 0.03  # the term taken out was not nothing


def test_the_geometric_pass_can_keep_the_photometric_source_masks(plane):
    """With keep_views each pixel chooses between the source the photometric pass chose for it (here the
    second for all) and the source whose depth map best confirms its plane, never among the others."""
    images, cams, depths, normal = plane
    rng = np.random.default_rng(2)
    start = (depths[0] * rng.uniform(0.97, 1.03, depths[0].shape)).astype(np.float32)
    inner = (slice(20, -20), slice(20, -20))

    def geometric(src_depths, keep_views):
        second = pm.State(start, normal, np.zeros_like(start), np.full(start.shape, 0b010, np.int64))
        return pm.geometric_depth(_checked(images, cams, src_depths), second, (1.0, 4.0), OPTIONS, seed=0,
                                  keep_views=keep_views)

    off = [d * 1.5 for d in depths[1:]]  # reprojection errors beyond geometric_max_error: none confirms
    assert (geometric(off, True).views == 0b010).all()
    assert (geometric(off, False).views[inner] != 0b010).mean() > 0.1  # chosen again, many take another
    confirmed = geometric([depths[1], *off[1:]], True)  # the first source's depth map confirms the plane
    assert set(np.unique(confirmed.views)) <= {0b001, 0b010}
    assert (confirmed.views[inner] == 0b001).mean() > 0.5
    assert np.median(np.abs(confirmed.depth[inner] / depths[0][inner] - 1.0)) < 0.005


def test_a_pixel_that_two_sources_see_can_pass_the_filter(plane):
    """The third source looks elsewhere: over top_k = 3 it counts as an uncorrelated window, not as
    the worst match, so the true plane still costs less than filter_max_cost (with the worst-match cost
    the mean could not go under (0 + 0 + 2) / 3)."""
    images, cams, depths, normal = plane
    away = pm.Camera(cams[3].K, cams[3].R, cams[3].t - np.array([10.0, 0.0, 0.0]))
    level = pm.make_level(images[0], images[1:], cams[0], [cams[1], cams[2], away])
    state = _state(depths[0], normal)
    pm.evaluate_state(level, state, THREE, pm.ALL_VIEWS)
    inner = (slice(8, -8), slice(8, -8))
    assert float(np.median(state.cost[inner])) < THREE.filter_max_cost


def test_a_pixel_that_one_source_sees_can_pass_the_filter(plane):
    """Ground at the edge of a survey that two photos share: the reference's other sources look
    elsewhere. Its mean over top_k = 3 takes two uncorrelated windows (at least 2 / 3), above
    filter_max_cost; the filter tests the cost over the sources that see the plane, so it keeps the
    true plane that the one source's depth map confirms, and still drops a wrong one."""
    images, cams, depths, normal = plane
    away = [pm.Camera(c.K, c.R, c.t - np.array([10.0, 0.0, 0.0])) for c in cams[2:]]
    empty = np.zeros_like(depths[0])
    view = pm.checked(images[0], images[1:], cams[0], [cams[1], *away], [depths[1], empty, empty])
    inner = (slice(12, -12), slice(24, -12))  # (the one source, to the right, misses the left columns)
    true = _costed(view, depths[0], normal, THREE)
    assert float(np.min(true.cost[inner])) > 2 / 3 > THREE.filter_max_cost
    kept = pm.filter_depth(view, true, THREE_CONFIRMED)
    assert np.mean(kept.depth[inner] > 0) > 0.95
    assert float(np.median(kept.cost[inner])) < 0.2  # the one source's own matching cost
    wrong = pm.filter_depth(view, _costed(view, depths[0] * 1.05, normal, THREE), THREE_CONFIRMED)
    assert not wrong.depth[inner].any()


def test_a_well_matched_pixel_no_source_map_confirms_is_kept(plane):
    """Surface the sources' own depth maps miss (here: they hold none): no source confirms the true
    plane, which matches well, so filter_unconfirmed_cost alone keeps it; a plane 20 % off (shifted by
    about 3 px in the sources) matches worse and still goes, and with the option off (0) the unconfirmed
    true plane goes too."""
    images, cams, depths, normal = plane
    empty = [np.zeros_like(d) for d in depths[1:]]
    view = _checked(images, cams, empty)
    inner = (slice(25, -25), slice(25, -25))
    true = _costed(view, depths[0], normal)
    assert OPTIONS.filter_unconfirmed_cost > 0
    assert np.mean(pm.filter_depth(view, true, OPTIONS).depth[inner] > 0) > 0.95
    assert not pm.filter_depth(view, true, CONFIRMED).depth.any()
    wrong = _costed(view, depths[0] * 1.2, normal)
    assert np.mean(pm.filter_depth(view, wrong, OPTIONS).depth[inner] > 0) < 0.05


def test_a_surface_that_one_source_sees_is_found_where_the_others_see_something_else(plane):
    """A walk's corner: one source sees the reference's surface, the other two see other things
    there. A hypothesis costs its best source's match (top_k 1), so the true plane wins; as a mean over
    three sources it pays two uncorrelated windows, and planes that half-match them win instead."""
    images, cams, depths, normal = plane
    elsewhere, _, _, _ = _plane_scene(seed=5)
    sources = [images[1], elsewhere[2], elsewhere[3]]
    inner = (slice(12, -12), slice(24, -12))  # (the one source, to the right, misses the left columns)
    found = {}
    for name, options in (("best", OPTIONS), ("mean of three", THREE)):
        state = pm.photometric_depth(images[0], sources, cams[0], cams[1:], (1.0, 4.0), options, seed=0)
        found[name] = np.mean(np.abs(state.depth - depths[0])[inner] < 0.01 * depths[0][inner])
    assert OPTIONS.top_k == 1
    assert found["best"] > 0.95 and found["mean of three"] < 0.8


def test_a_fine_pixel_starts_with_the_sources_of_its_nearest_coarse_pixels():
    """Above the level under the coarsest, a pixel chooses its sources among those its coarse pixel
    and the neighbours across the nearer edges chose (not among all: matching every source at every
    pixel was a fifth of the photometric pass)."""
    hc, wc = 3, 4
    bit = np.arange(hc * wc).reshape(hc, wc)
    views_coarse = (1 << bit).astype(np.int64)
    K = np.array([[50.0, 0, 4], [0, 50.0, 3], [0, 0, 1]])
    coarse_kinv = np.linalg.inv(np.diag([0.5, 0.5, 1.0]) @ K)
    depth = np.zeros((2 * hc, 2 * wc), np.float32)
    normal = np.zeros((2 * hc, 2 * wc, 3), np.float32)
    views = np.zeros((2 * hc, 2 * wc), np.int64)
    coarse_normal = np.broadcast_to(np.float32([0, 0, -1]), (hc, wc, 3)).copy()
    pm.upsample(np.ones((hc, wc), np.float32), coarse_normal, views_coarse, coarse_kinv, np.linalg.inv(K),
                depth, normal, views)
    assert views[0, 0] == 1 << bit[0, 0]  # the image's corner: no neighbour
    assert views[1, 1] == sum(1 << b for b in bit[:2, :2].ravel())  # the four nearest
    assert views[0, 3] == (1 << bit[0, 1]) | (1 << bit[0, 2])  # its coarse pixel and the one to the right
    own = 1 << bit[np.arange(2 * hc)[:, None] // 2, np.arange(2 * wc)[None, :] // 2]
    assert np.all(views & own)
    assert np.allclose(depth, 1.0) and np.allclose(normal[..., 2], -1.0)


def test_narrowed_sources_are_chosen_among_the_mask_only(plane):
    images, cams, depths, normal = plane
    elsewhere, _, _, _ = _plane_scene(seed=5)
    level = pm.make_level(images[0], [images[1], elsewhere[2], elsewhere[3]], cams[0], cams[1:], 1.0)
    inner = (slice(12, -12), slice(24, -12))
    chosen = {}
    for mode in (pm.SELECT_VIEWS, pm.NARROW_VIEWS):
        state = pm.State(depths[0].copy(), normal.copy(), np.zeros_like(depths[0]),
                         np.full(depths[0].shape, 0b110, np.int64))
        pm.evaluate_state(level, state, OPTIONS, mode)
        chosen[mode] = state.views[inner]
    assert np.mean(chosen[pm.SELECT_VIEWS] == 0b001) > 0.95  # the one source that sees the plane
    assert np.isin(chosen[pm.NARROW_VIEWS], [0b010, 0b100]).all()


def test_a_surface_that_one_source_sees_is_found_at_the_finest_of_three_levels(plane):
    images, cams, depths, normal = plane
    elsewhere, _, _, _ = _plane_scene(seed=5)
    options = dataclasses.replace(OPTIONS, pyramid_min_size=24)
    assert pm.pyramid_levels(images[0].shape, options) == 3
    state = pm.photometric_depth(images[0], [elsewhere[2], images[1], elsewhere[3]], cams[0],
                                 [cams[2], cams[1], cams[3]], (1.0, 4.0), options, seed=0)
    inner = (slice(12, -12), slice(24, -12))
    found = np.abs(state.depth - depths[0])[inner] < 0.01 * depths[0][inner]
    assert found.mean() > 0.9
    assert np.mean(state.views[inner][found] == 0b010) > 0.95


def test_a_neighbours_source_travels_with_its_plane(plane):
    """Above the coarsest level each pixel is matched against the source chosen for its upsampled plane.
    Where that plane was wrong, so may the source be: here the right part of the reference holds a plane
    5 % off, matched against a source that sees something else there. The left part holds the true plane
    with the one source that sees it. A neighbour's plane is tested with the neighbour's source too, so
    the true plane spreads across the right part and takes its source along; judged by the wrong source
    alone (the pixel's own), it would not."""
    images, cams, depths, normal = plane
    elsewhere, _, _, _ = _plane_scene(seed=5)
    level = pm.make_level(images[0], [images[1], elsewhere[2], elsewhere[3]], cams[0], cams[1:], 1.0)
    right = (slice(12, -12), slice(48, -12))
    start = depths[0].copy()
    start[:, 48:] *= 1.05
    state = pm.State(start, normal.copy(), np.zeros_like(start), np.full(start.shape, 0b001, np.int64))
    state.views[:, 48:] = 0b010
    pm.evaluate_state(level, state, OPTIONS, pm.KEEP_VIEWS)
    pm.sweeps(level, state, OPTIONS, (1.0, 4.0), iterations=2, perturbation=0.01, random_candidates=False,
              far_regions=True, seed=0, first_sweep=0)
    found = np.abs(state.depth - depths[0])[right] < 0.01 * depths[0][right]
    assert found.mean() > 0.95
    assert (state.views[right][found] == 0b001).all()


def test_the_uniform_side_of_an_edge_gets_no_depth():
    """Pixels of a flat light grey region beside a textured one match on the texture alone (their
    bilateral window's variance comes from across the edge): given the edge's plane they pass the cost and the
    consistency tests, as a sky pixel beside a pole does at the pole's depth. Their own side of the
    window is untextured, so the filter drops them and keeps the textured side."""
    images, cams, depths, normal = _plane_scene(uniform_from=0.0)
    view = _checked(images, cams, depths[1:])
    state = _costed(view, depths[0], normal)
    without = dataclasses.replace(OPTIONS, min_texture=0.0)  # neither texture test
    old, new = pm.filter_depth(view, state, without), pm.filter_depth(view, state, OPTIONS)
    grey = np.abs(images[0] - SKY) < 1e-6
    edge = int(np.argmax(grey[HEIGHT // 2]))  # first grey column on the middle row
    rows = slice(12, -12)
    halo = (slice(12, -12), slice(edge + 1, edge + 3))  # grey, with texture in most of the window
    assert grey[halo].all()
    window, _, sigma_color, min_var, _ = pm._kernel_params(OPTIONS)
    weights, centred = np.empty(window[2] ** 2), np.empty(window[2] ** 2)
    spread = view.level.spread(OPTIONS)
    variances = [pm.reference_patch(images[0], x, y, window, spread, sigma_color, weights, centred)
                 for y in range(12, HEIGHT - 12) for x in range(edge + 1, edge + 3)]
    assert np.mean(np.array(variances) > min_var) > 0.8  # the matching's texture test lets most through
    assert np.mean(old.depth[halo] > 0) > 0.8
    textured = (rows, slice(12, edge - 6))
    assert not new.depth[halo].any()
    assert np.mean(new.depth[textured] > 0) >= np.mean(old.depth[textured] > 0) - 0.02 > 0.9


def test_a_plane_seen_at_a_grazing_angle_is_found_sooner_when_its_normal_is_known():
    """The ground seen from eye height (recon.mvs.ground_normal): a plane tilted 75 degrees from the view,
    two sweeps at the coarsest level. Testing each pixel's plane turned to the known normal (either sign)
    finds the plane at more pixels than the random normals alone do."""
    images, cams, depths, normal = _plane_scene(tilt_deg=75.0)
    options = dataclasses.replace(OPTIONS, iterations=2)
    truth = normal[0, 0].astype(np.float64)  # R = I: the camera frame is the world's

    def found(ground):
        state = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.0, 8.0), options, seed=3,
                                     ground=ground)
        return np.mean(np.abs(state.depth - depths[0]) <= 0.01 * depths[0])

    without = found(None)
    assert found(truth) > without + 0.08
    assert found(-truth) > without + 0.08


def _sphere_scene(radius: float = 0.35, depth: float = 2.0, seed: int = 0):
    """Images (float32 [0, 1], 3 x 3 samples a pixel), cameras and true depth maps (0 off the sphere) of views
    of a sphere at ``depth`` painted with a smooth random pattern of its 3D points, in front of a flat sky."""
    rng = np.random.default_rng(seed)
    directions, frequencies, phases = rng.normal(size=(24, 3)), rng.uniform(15, 45, 24), rng.uniform(0, 2 * np.pi, 24)
    f = 1.2 * WIDTH
    K = np.array([[f, 0, WIDTH / 2], [0, f, HEIGHT / 2], [0, 0, 1]])
    middle = np.array([0.0, 0.0, depth])

    def hits(centre, dx, dy):
        u, v = np.meshgrid(np.arange(WIDTH) + dx, np.arange(HEIGHT) + dy)
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        b = rays @ (centre - middle)
        disc = b * b - (np.sum((centre - middle) ** 2) - radius**2)
        return disc > 0, centre + (-b - np.sqrt(np.maximum(disc, 0)))[..., None] * rays

    images, cams, depths = [], [], []
    for centre in map(np.asarray, CENTRES):
        image = np.zeros((HEIGHT, WIDTH))
        for dy in (1 / 6, 0.5, 5 / 6):
            for dx in (1 / 6, 0.5, 5 / 6):
                on, X = hits(centre, dx, dy)
                pattern = 0.5 + 0.2 / np.sqrt(12) * np.sum(np.sin(X @ directions.T * frequencies + phases), axis=-1)
                image += np.where(on, pattern, SKY) / 9
        on, X = hits(centre, 0.5, 0.5)
        images.append(image.astype(np.float32))
        cams.append(pm.Camera(K, np.eye(3), -centre))
        depths.append(np.where(on, X[..., 2] - centre[2], 0.0).astype(np.float32))
    return images, cams, depths


def test_a_narrowed_window_leans_less_behind_a_curved_surface():
    """A plane fitted over a window lies behind a convex surface: on a ball 40 px across, the full window's
    depths lie a median 0.44 % of the depth behind it. Where the window is textured enough, its weight
    narrows (mvs.narrow_sigma), and the lean about halves (0.24 %)."""
    images, cams, depths = _sphere_scene()
    inner = cv2.erode((depths[0] > 0).astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
    lean = {}
    for narrow in (0.0, 2.0):
        options = dataclasses.replace(OPTIONS, iterations=6, narrow_sigma=narrow)
        state = pm.photometric_depth(images[0], images[1:], cams[0], cams[1:], (1.2, 3.0), options, seed=0)
        lean[narrow] = float(np.median((state.depth - depths[0])[inner] / depths[0][inner]))
    assert lean[0.0] > 0.002  # behind
    assert 0.0 < lean[2.0] < 0.7 * lean[0.0]


def test_the_window_narrows_where_its_texture_lies_near_its_centre_and_stands_above_the_noise():
    narrowing = dataclasses.replace(OPTIONS, narrow_sigma=2.0)
    rng = np.random.default_rng(4)
    image = np.full((60, 120), 0.5, np.float32)
    image[:, :60] = cv2.resize(rng.random((15, 15)).astype(np.float32), (60, 60), interpolation=cv2.INTER_CUBIC)
    image[20:40, 20:40] = 0.5  # a flat patch inside the texture
    noisy = image + rng.normal(0.0, 0.02, image.shape).astype(np.float32)
    wide, narrow = 0.5 / OPTIONS.window_radius**2, 0.5 / narrowing.narrow_sigma**2
    spread = pm.matching_spread(image, narrowing)
    assert np.mean(spread[5:15, 5:55] == narrow) > 0.9  # textured
    assert (spread[:, 70:] == wide).all()  # flat
    assert (spread[25:35, 25:35] == wide).all()  # the flat patch, its texture at the window's edge
    assert (pm.matching_spread(image, OPTIONS) == wide).all()  # the default: no narrowing
    # in noise of 0.02 (the estimate within 10 %), the texture's finer detail no longer stands 3 times above it
    assert pm.noise_sigma(noisy) == pytest.approx(0.02, rel=0.1)
    assert np.mean(pm.matching_spread(noisy, narrowing)[5:15, 5:55] == narrow) < np.mean(spread[5:15, 5:55] == narrow)
