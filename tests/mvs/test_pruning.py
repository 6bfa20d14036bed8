"""Abandoning a hypothesis that cannot beat the pixel's best cost changes no decision of PatchMatch."""

import numpy as np

from recon.mvs import patchmatch as pm

WIDTH, HEIGHT = 64, 48


def _views(n_sources: int):
    rng = np.random.default_rng(1)
    K = np.array([[60.0, 0, WIDTH / 2], [0, 60.0, HEIGHT / 2], [0, 0, 1]])
    ref = pm.Camera(K, np.eye(3), np.zeros(3))
    sources = [pm.Camera(K, np.eye(3), np.array([-0.1 * (i + 1), 0.03 * i, 0.0])) for i in range(n_sources)]
    images = [rng.random((HEIGHT, WIDTH)).astype(np.float32) for _ in range(n_sources + 1)]
    return images[0], images[1:], ref, sources


def _costs(n_sources: int, mask: int, bound_of):
    """(full, with the bound) costs of random planes at random pixels; ``bound_of(full)`` the bound."""
    ref, srcs, ref_cam, src_cams = _views(n_sources)
    g = pm.view_geometry(ref_cam, src_cams)
    stack, dims = pm.stack_images(srcs)
    window = pm.window_grid(5, 2)
    n = window[2] * window[2]
    weights, centred = np.empty(n), np.empty(n)
    costs, scratch = np.empty(n_sources), np.empty(n_sources)
    no_depths = np.zeros((n_sources, 1, 1), np.float32)
    spread = np.full(ref.shape, 0.5 / 5.0**2)  # the full window's spatial weight at every pixel
    rng = np.random.default_rng(2)
    full, bounded = [], []
    for _ in range(400):
        x, y = int(rng.integers(6, WIDTH - 6)), int(rng.integers(6, HEIGHT - 6))
        ref_var = pm.reference_patch(ref, x, y, window, spread, 0.2, weights, centred)
        normal = np.array([rng.normal(0, 0.2), rng.normal(0, 0.2), -1.0])
        normal /= np.linalg.norm(normal)
        depth = rng.uniform(1.0, 3.0)
        args = (x, y, depth, *normal, mask, weights, centred, ref_var, window, g.kinv, g.A, g.b, stack, dims,
                no_depths, g.M, g.c, 0.0, 3.0, 3, 1e-5, costs, scratch)
        cost = pm.hypothesis_cost(*args)
        full.append(cost)
        bounded.append(pm.hypothesis_cost(*args, bound_of(cost)))
    return np.array(full), np.array(bounded)


def test_a_bound_changes_no_comparison_with_it():
    rng = np.random.default_rng(3)
    bounds = []

    def bound_of(cost):  # around the hypothesis' own cost: the comparisons that matter
        bounds.append(max(0.0, cost + rng.normal(0, 0.3)))
        return bounds[-1]

    full, bounded = _costs(3, 0b111, bound_of)
    bounds = np.array(bounds)
    np.testing.assert_array_equal(bounded < bounds, full < bounds)
    np.testing.assert_array_equal(bounded[full < bounds], full[full < bounds])  # the winners' costs are exact
    abandoned = bounded != full
    assert abandoned.sum() > 20  # the bound did cut work short
    assert np.all(bounded[abandoned] > bounds[abandoned])


def test_no_bound_applies_while_an_unmatched_source_could_leave_the_best_k():
    full, bounded = _costs(5, 0b11111, lambda cost: 0.0)  # 5 sources, mean of the best 3
    np.testing.assert_array_equal(bounded, full)
