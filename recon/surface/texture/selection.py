"""View selection: one photo per face, by alpha-expansion graph cuts on the face adjacency graph.

Energy (Waechter et al. 2014): sum over faces of a data cost plus a Potts term on every pair of adjacent
faces with different views. The data cost of view j for face f is area_f * (1 - q_fj / max_j q_fj)
(areas relative to the mean face area, q from :func:`recon.surface.texture.views.view_quality`), so the
best view costs nothing; the Potts weight is ``smoothness`` times the shared edge's length relative to
the mean edge length. Each expansion move is a binary min cut (Kolmogorov and Zabih 2004) solved with
:func:`recon.surface.texture.maxflow.min_cut`.
"""

from __future__ import annotations

import logging

import numpy as np

from recon.surface.texture.maxflow import min_cut

log = logging.getLogger(__name__)

def data_costs(quality: np.ndarray, face_area: np.ndarray) -> np.ndarray:
    """Data cost (F, N) of labelling each face with each view; inf where the view does not see it."""
    best = quality.max(axis=1, keepdims=True)
    rel_area = face_area / max(face_area.mean(), 1e-30)
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = rel_area[:, None] * (1.0 - quality / best)
    return np.where(quality > 0, cost, np.inf)


def energy(cost: np.ndarray, labels: np.ndarray, pairs: np.ndarray, weights: np.ndarray) -> float:
    """Total data plus Potts energy of a labelling (faces labelled -1 contribute no data cost)."""
    seen = labels >= 0
    data = cost[np.flatnonzero(seen), labels[seen]].sum()
    return float(data + weights[labels[pairs[:, 0]] != labels[pairs[:, 1]]].sum())


def _expand(cost, labels, alpha, pairs, weights) -> np.ndarray | None:
    """The optimal alpha-expansion move from ``labels``; None when it changes nothing."""
    var = np.isfinite(cost[:, alpha]) & (labels != alpha) & (labels >= 0)
    n = int(var.sum())
    if n == 0:
        return None
    node = np.full(len(labels), -1, np.int64)
    node[var] = np.arange(n)
    cur = labels[var]
    u0 = cost[var, cur].astype(np.float64)
    u1 = cost[var, alpha].astype(np.float64)
    la, lb = labels[pairs[:, 0]], labels[pairs[:, 1]]
    va, vb = var[pairs[:, 0]], var[pairs[:, 1]]
    # one end variable, the other fixed: unary terms
    for a_var, a, lf in ((va & ~vb, pairs[:, 0], lb), (vb & ~va, pairs[:, 1], la)):
        idx = node[a[a_var]]
        np.add.at(u0, idx, weights[a_var] * (labels[a[a_var]] != lf[a_var]))
        np.add.at(u1, idx, weights[a_var] * (lf[a_var] != alpha))
    # both ends variable: A = w[la != lb], B = C = w, D = 0
    both = va & vb
    pa, pb, w = node[pairs[both, 0]], node[pairs[both, 1]], weights[both]
    big_a = w * (la[both] != lb[both])
    np.add.at(u1, pa, w - big_a)
    np.add.at(u1, pb, -w)
    _, keep = min_cut(u1 - u0, pa, pb, 2 * w - big_a)
    switch = ~keep
    if not switch.any():
        return None
    out = labels.copy()
    out[np.flatnonzero(var)[switch]] = alpha
    return out


def select_views(quality: np.ndarray, pairs: np.ndarray, face_area: np.ndarray, edge_length: np.ndarray,
                 smoothness: float = 1.0, cycles: int = 3, seed: int = 0) -> np.ndarray:
    """A view index per face (-1: no view sees it) minimising data cost plus ``smoothness`` x Potts."""
    cost = data_costs(quality, face_area)
    seen = quality.max(axis=1) > 0
    labels = np.where(seen, quality.argmax(axis=1), -1)
    if smoothness <= 0 or cycles == 0 or len(pairs) == 0:
        return labels
    weights = smoothness * edge_length / max(edge_length.mean(), 1e-30)
    rng = np.random.default_rng(seed)
    e = energy(cost, labels, pairs, weights)
    log.debug("view selection: initial energy %.4g", e)
    for cycle in range(cycles):
        improved = False
        for alpha in rng.permutation(quality.shape[1]):
            new = _expand(cost, labels, int(alpha), pairs, weights)
            if new is None:
                continue
            e_new = energy(cost, new, pairs, weights)
            if e_new < e - 1e-9:
                labels, e, improved = new, e_new, True
        log.debug("view selection: cycle %d energy %.4g", cycle, e)
        if not improved:
            break
    return labels
