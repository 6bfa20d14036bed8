"""Global seam levelling (Lempitsky and Ivanov 2007; Waechter et al. 2014, section 4.2).

Each patch (faces sharing one photo) gets an additive RGB correction g at each of its vertices; a vertex
on a seam has one unknown per patch it belongs to. With f the colour a patch's photo shows at a seam
vertex (averaged along the seam edges next to it, weighted towards the vertex), the corrections minimise

    sum_seam-vertices (f_a + g_a - f_b - g_b)^2 + weight * sum_patch-edges (g_i - g_j)^2 + eps * sum g^2,

a sparse symmetric positive definite system solved once for the three channels. The correction of a
texel is the barycentric interpolation of its face's corner corrections.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from recon.imaging.pixels import sample_bilinear
from recon.surface.indexing import unique_rows
from recon.surface.texture.views import unobstructed

log = logging.getLogger(__name__)

_SAMPLES = 8  # colour samples along each seam edge
_RIDGE = 1e-4  # fixes the common offset of connected patches (the system is singular without it)


def patch_vertices(faces: np.ndarray, patch: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, int]:
    """An unknown per (patch, vertex) pair: its index for each face corner (F, 3; -1 on unseen faces) and
    the number of unknowns."""
    corner = np.full(faces.shape, -1, np.int64)
    seen = labels >= 0
    keys = np.stack([np.repeat(patch[seen], 3), faces[seen].ravel()], axis=1)
    uniq, inv = unique_rows(keys, return_inverse=True)
    corner[seen] = inv.reshape(-1, 3)
    return corner, len(uniq)


def _corner_of(faces, corner_pv, face, vertex):
    slot = np.argmax(faces[face] == vertex[:, None], axis=1)
    return corner_pv[face, slot]


def seam_samples(vertices, faces, labels, patch, pairs, edge_vertices, images, cameras, depths):
    """Seam edges between patches and the colour each side's photo shows along them.

    Returns the seam edges' face pairs (S, 2), their vertices (S, 2), colours (S, 2, K, 3) sampled at K
    points t = (k + 0.5) / K from the first to the second vertex in each face's own photo, and whether both
    photos see each point clear of occluders and silhouettes (S, K)."""
    a, b = pairs[:, 0], pairs[:, 1]
    seam = (patch[a] != patch[b]) & (labels[a] >= 0) & (labels[b] >= 0)
    fpairs, ev = pairs[seam], edge_vertices[seam]
    t = (np.arange(_SAMPLES) + 0.5) / _SAMPLES
    pts = vertices[ev[:, 0], None] * (1 - t[:, None]) + vertices[ev[:, 1], None] * t[:, None]  # S, K, 3
    colors = np.zeros((len(fpairs), 2, _SAMPLES, 3), np.float32)
    clear = np.ones((len(fpairs), _SAMPLES), bool)
    for side in (0, 1):
        lab = labels[fpairs[:, side]]
        for j in np.unique(lab):
            sel = np.flatnonzero(lab == j)
            cam = cameras[j]
            p = pts[sel].reshape(-1, 3)
            seen, uv = unobstructed(p, cam, depths[j])
            colors[sel, side] = sample_bilinear(images[j], uv[:, 0], uv[:, 1]).reshape(len(sel), _SAMPLES, -1)
            clear[sel] &= seen.reshape(len(sel), _SAMPLES)
    return fpairs, ev, colors, clear


def level_seams(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, patch: np.ndarray,
                pairs: np.ndarray, edge_vertices: np.ndarray, images: Sequence[np.ndarray], cameras: Sequence,
                depths: Sequence[np.ndarray], weight: float) -> np.ndarray:
    """Per-corner colour corrections (F, 3, 3) in 0-255 units (zero on unseen faces). ``images`` are
    H x W x 3 arrays (uint8 or float in 0-255), ``depths`` the mesh's depth map in each view (seam samples
    that a photo does not see clearly are left out)."""
    faces = np.asarray(faces, np.int64)
    corner_pv, n = patch_vertices(faces, patch, labels)
    fpairs, ev, colors, clear = seam_samples(vertices, faces, labels, patch, pairs, edge_vertices, images,
                                             cameras, depths)
    corr = np.zeros((len(faces), 3, 3), np.float32)
    # f: each side's colour at each seam vertex, averaged over the seam edges there, weighted to the vertex
    t = (np.arange(_SAMPLES) + 0.5) / _SAMPLES
    f_sum = np.zeros((n, 3))
    f_w = np.zeros(n)
    rows = []
    for end, wt in ((0, 1 - t), (1, t)):
        wts = wt[None, :] * clear  # S, K
        pv = [_corner_of(faces, corner_pv, fpairs[:, side], ev[:, end]) for side in (0, 1)]
        for side in (0, 1):
            np.add.at(f_sum, pv[side], np.einsum("sk,skc->sc", wts, colors[:, side]))
            np.add.at(f_w, pv[side], wts.sum(axis=1))
        used = wts.sum(axis=1) > 0
        rows.append(np.stack(pv, axis=1)[used])
    rows = np.concatenate(rows)
    if len(rows) == 0:
        return corr
    f = f_sum / np.maximum(f_w, 1e-12)[:, None]
    seam_pairs = unique_rows(rows)
    # regulariser: patch-vertex pairs joined by an edge of a face of that patch
    seen = labels >= 0
    c = corner_pv[seen]
    reg = np.sort(np.concatenate([c[:, [0, 1]], c[:, [1, 2]], c[:, [2, 0]]]), axis=1)
    reg = unique_rows(reg)

    def difference(p):
        m = len(p)
        return sp.csr_matrix((np.r_[np.ones(m), -np.ones(m)], (np.r_[np.arange(m), np.arange(m)],
                                                                   np.r_[p[:, 0], p[:, 1]])), shape=(m, n))

    a_seam, a_reg = difference(seam_pairs), difference(reg)
    lhs = (a_seam.T @ a_seam + weight * (a_reg.T @ a_reg) + _RIDGE * sp.identity(n)).tocsc()
    rhs = a_seam.T @ (f[seam_pairs[:, 1]] - f[seam_pairs[:, 0]])
    g = splu(lhs).solve(np.ascontiguousarray(rhs))
    before = np.abs(f[seam_pairs[:, 0]] - f[seam_pairs[:, 1]]).mean()
    after = np.abs(f[seam_pairs[:, 0]] + g[seam_pairs[:, 0]] - f[seam_pairs[:, 1]] - g[seam_pairs[:, 1]]).mean()
    log.info("levelling: %d unknowns, %d seam constraints, seam colour difference %.2f -> %.2f",
             n, len(seam_pairs), before, after)
    corr[seen] = g[c].astype(np.float32)
    return corr
