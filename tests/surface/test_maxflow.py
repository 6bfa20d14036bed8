import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import maximum_flow

from recon.surface.texture.maxflow import min_cut


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
