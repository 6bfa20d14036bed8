import itertools

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import maximum_flow

from recon.surface.texture.maxflow import min_cut
from recon.surface.texture.selection import _expand, data_costs, energy


def _random_graph(rng, n, e):
    tails = rng.integers(0, n, e)
    heads = rng.integers(0, n, e)
    keep = tails != heads
    tails, heads = tails[keep], heads[keep]
    caps = rng.integers(0, 20, len(tails)).astype(float)
    rev = rng.integers(0, 20, len(tails)).astype(float)
    terminal = rng.integers(-30, 31, n).astype(float)
    return terminal, tails, heads, caps, rev


def _scipy_flow(terminal, tails, heads, caps, rev):
    n = len(terminal)
    s, t = n, n + 1
    src = np.flatnonzero(terminal > 0)
    snk = np.flatnonzero(terminal < 0)
    rows = np.concatenate([tails, heads, np.full(len(src), s), snk])
    cols = np.concatenate([heads, tails, src, np.full(len(snk), t)])
    data = np.concatenate([caps, rev, terminal[src], -terminal[snk]]).astype(np.int32)
    g = sp.csr_matrix((data, (rows, cols)), shape=(n + 2, n + 2))
    return maximum_flow(g, s, t).flow_value


def _cut_value(terminal, tails, heads, caps, rev, source_side):
    cut = terminal[(terminal > 0) & ~source_side].sum() - terminal[(terminal < 0) & source_side].sum()
    cut += caps[source_side[tails] & ~source_side[heads]].sum()
    cut += rev[source_side[heads] & ~source_side[tails]].sum()
    return cut


@pytest.mark.parametrize("seed", range(20))
def test_flow_and_cut_match_scipy(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 300))
    g = _random_graph(rng, n, int(rng.integers(1, 4 * n)))
    flow, side = min_cut(*g)
    expected = _scipy_flow(*g)
    assert flow == pytest.approx(expected)
    assert _cut_value(*g, side) == pytest.approx(expected)  # the returned side is a minimum cut


def test_grid_segmentation():
    """A 2-D grid with a noisy disc: strong smoothing recovers the disc exactly."""
    rng = np.random.default_rng(0)
    s = 60
    yy, xx = np.mgrid[:s, :s]
    disc = (yy - 30) ** 2 + (xx - 28) ** 2 < 15**2
    evidence = np.where(disc, 1.0, -1.0) + rng.normal(0, 0.8, (s, s))
    idx = np.arange(s * s).reshape(s, s)
    tails = np.concatenate([idx[:, :-1].ravel(), idx[:-1].ravel()])
    heads = np.concatenate([idx[:, 1:].ravel(), idx[1:].ravel()])
    w = np.full(len(tails), 1.5)
    _, side = min_cut(evidence.ravel(), tails, heads, w, w)
    # source side = label "disc" (cutting its source edge costs the positive evidence)
    assert (side.reshape(s, s) == disc).mean() > 0.99


@pytest.mark.parametrize("seed", range(10))
def test_cut_is_the_least_of_all_cuts(seed):
    """Real-valued capacities: the flow equals the cheapest of all 2^n source sides (brute force)."""
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(1, 11))
    terminal = rng.normal(0, 3, n)
    tails, heads = rng.integers(0, n, 3 * n), rng.integers(0, n, 3 * n)
    keep = tails != heads
    tails, heads = tails[keep], heads[keep]
    caps, rev = rng.uniform(0, 4, len(tails)), rng.uniform(0, 4, len(tails))
    flow, side = min_cut(terminal, tails, heads, caps, rev)
    best = min(_cut_value(terminal, tails, heads, caps, rev, np.array(s, bool))
               for s in itertools.product((False, True), repeat=n))
    assert flow == pytest.approx(best) and _cut_value(terminal, tails, heads, caps, rev, side) == pytest.approx(best)


def test_empty_graph():
    flow, side = min_cut(np.zeros(0), np.zeros(0, int), np.zeros(0, int), np.zeros(0))
    assert flow == 0 and side.shape == (0,)


@pytest.mark.parametrize("seed", range(10))
def test_expansion_move_is_the_best_binary_move(seed):
    """View selection's alpha-expansion through min_cut: of every labelling that keeps each face's view or
    switches it to alpha, the move found has the least energy (brute force over the 2^n moves)."""
    rng = np.random.default_rng(seed)
    faces, views = 9, 3
    quality = rng.uniform(0, 1, (faces, views)) * (rng.uniform(0, 1, (faces, views)) > 0.2)
    quality[:, 0] += 0.01  # every face seen by some view
    pairs = np.array([(i, j) for i in range(faces) for j in range(i + 1, faces) if rng.uniform() < 0.35])
    weights = rng.uniform(0.1, 1.5, len(pairs))
    cost = data_costs(quality, rng.uniform(0.5, 2.0, faces))
    labels = quality.argmax(axis=1)
    for alpha in range(views):
        move = _expand(cost, labels, alpha, pairs, weights)
        got = energy(cost, labels if move is None else move, pairs, weights)
        can = np.flatnonzero(np.isfinite(cost[:, alpha]) & (labels != alpha))
        best = energy(cost, labels, pairs, weights)
        for switch in itertools.product((False, True), repeat=len(can)):
            trial = labels.copy()
            trial[can[np.array(switch, bool)]] = alpha
            best = min(best, energy(cost, trial, pairs, weights))
        assert got == pytest.approx(best)
