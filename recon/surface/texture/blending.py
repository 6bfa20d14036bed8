"""Local seam blending (after Waechter et al. 2014, section 4.2, "local seam levelling").

After global levelling, colours still differ a little across seams (the correction is exact only at
vertices). Along every seam edge, points a half texel apart are looked up in both patches' charts; the
texel under each lookup is pinned to half the difference (each side moves to the mean), and the change
fades out harmonically over a band of texels of the same chart: a Laplace problem with the pinned texels
fixed, zero change beyond the band and free (Neumann) edges at the chart's rectangle, solved by
successive over-relaxation (the band is narrow, so it converges in a few dozen sweeps). Adding a harmonic
function keeps the photo's gradients, so this is Poisson editing with the photo as guidance.

Seam edges shorter than ``MIN_SEAM_TEXELS`` in both charts are left out. Where a mesh's faces are as
small as its texels (a small object seen from close by), the texel pinned under a lookup spans several faces
along and across the seam, so the change pinned to it is not the colour difference at one seam point, and
the band spreads it over faces it does not belong to. On the zoo, blending every seam edge lowered held-out
PSNR by 0.81 dB on masked_object (seam edges a median 0.77 texels long) and 0.23 dB on turntable_black
(1.59), below their vertex colours; lookups in a smoothed atlas (Gaussian, 1.5 texels) did not help, a band
of 2 texels recovered half. Elsewhere (median 3.8-4.3 texels) few edges are left out and no scene moved by
more than 0.03 dB (docs/DECISIONS.md).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numba
import numpy as np
from scipy import ndimage

from recon.imaging.pixels import sample_bilinear
from recon.surface.texture.atlas import Layout
from recon.surface.texture.views import unobstructed

log = logging.getLogger(__name__)

#: seam edges shorter than this in both charts (texels) are left out of the blending (module doc)
MIN_SEAM_TEXELS = 2.0


@numba.njit(cache=True)
def _harmonic(neighbour, rhs, degree, tol, max_sweeps):
    """Solve degree_i x_i - sum_(unknown neighbours j) x_j = rhs_i by successive over-relaxation."""
    m = len(degree)
    x = np.zeros((m, 3))
    omega = 1.9
    for _ in range(max_sweeps):
        change = 0.0
        for i in range(m):
            if degree[i] == 0:
                continue
            for c in range(3):
                acc = rhs[i, c]
                for k in range(4):
                    j = neighbour[i, k]
                    if j >= 0:
                        acc += x[j, c]
                step = omega * (acc / degree[i] - x[i, c])
                x[i, c] += step
                change = max(change, abs(step))
        if change < tol:
            break
    return x


def chart_map(lay: Layout) -> np.ndarray:
    """The chart index of each atlas texel (-1 outside charts)."""
    out = np.full((lay.height, lay.width), -1, np.int64)
    for k, c in enumerate(lay.charts):
        out[c.y:c.y + c.h, c.x:c.x + c.w] = k
    return out


def _edge_corners(faces, corner_xy, face, v0, v1):
    slot0 = np.argmax(faces[face] == v0[:, None], axis=1)
    slot1 = np.argmax(faces[face] == v1[:, None], axis=1)
    return corner_xy[face, slot0], corner_xy[face, slot1]


def blend_seams(atlas: np.ndarray, lay: Layout, vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                patch: np.ndarray, pairs: np.ndarray, edge_vertices: np.ndarray, cameras: Sequence,
                depths: Sequence[np.ndarray], band: int) -> np.ndarray:
    """The atlas (H, W, 3; float) with the colour differences left along seams blended over ``band`` texels;
    seam points that either photo does not see clearly (``depths``: the mesh's depth map per view) are left
    out."""
    h, w = atlas.shape[:2]
    a, b = pairs[:, 0], pairs[:, 1]
    seam = (patch[a] != patch[b]) & (labels[a] >= 0) & (labels[b] >= 0)
    if not seam.any():
        return atlas
    fa, fb, ev = a[seam], b[seam], edge_vertices[seam]
    a0, a1 = _edge_corners(faces, lay.corner_xy, fa, ev[:, 0], ev[:, 1])
    b0, b1 = _edge_corners(faces, lay.corner_xy, fb, ev[:, 0], ev[:, 1])
    longest = np.maximum(np.linalg.norm(a1 - a0, axis=1), np.linalg.norm(b1 - b0, axis=1))
    long_enough = longest >= MIN_SEAM_TEXELS
    short = int(np.count_nonzero(~long_enough))
    if not long_enough.any():
        log.info("seam blending: all %d seam edges shorter than %g texels, none blended", len(fa), MIN_SEAM_TEXELS)
        return atlas
    fa, fb, ev, longest = fa[long_enough], fb[long_enough], ev[long_enough], longest[long_enough]
    a0, a1, b0, b1 = a0[long_enough], a1[long_enough], b0[long_enough], b1[long_enough]
    count = np.ceil(2 * longest).astype(np.int64) + 1
    edge = np.repeat(np.arange(len(fa)), count)
    t = ((np.arange(len(edge)) - np.repeat(np.cumsum(count) - count, count)) + 0.5) / count[edge]
    clear = np.ones(len(edge), bool)
    point = vertices[ev[edge, 0]] * (1 - t[:, None]) + vertices[ev[edge, 1]] * t[:, None]
    for f in (fa, fb):
        lab = labels[f][edge]
        for j in np.unique(lab):
            sel = np.flatnonzero(lab == j)
            clear[sel] &= unobstructed(point[sel], cameras[j], depths[j])[0]
    edge, t = edge[clear], t[clear]
    if len(edge) == 0:
        return atlas
    pa = a0[edge] + (a1 - a0)[edge] * t[:, None]
    pb = b0[edge] + (b1 - b0)[edge] * t[:, None]
    ca = sample_bilinear(atlas, pa[:, 0], pa[:, 1])
    cb = sample_bilinear(atlas, pb[:, 0], pb[:, 1])
    half = 0.5 * (cb - ca)
    # pin the texel under each lookup to the mean change asked of it
    texel = np.concatenate([np.clip(np.floor(p).astype(np.int64), 0, [w - 1, h - 1]) for p in (pa, pb)])
    flat = texel[:, 1] * w + texel[:, 0]
    change = np.concatenate([half, -half])
    total = np.zeros((h * w, 3))
    hits = np.zeros(h * w)
    np.add.at(total, flat, change)
    np.add.at(hits, flat, 1)
    fixed = (hits > 0).reshape(h, w)
    delta = (total / np.maximum(hits, 1)[:, None]).reshape(h, w, 3)
    # harmonic fade over the band, inside each chart's rectangle
    charts = chart_map(lay)
    dist, (iy, ix) = ndimage.distance_transform_edt(~fixed, return_indices=True)
    unknown = (charts >= 0) & ~fixed & (dist <= band) & (charts[iy, ix] == charts)
    uy, ux = np.nonzero(unknown)
    m = len(uy)
    index = np.full((h, w), -1, np.int64)
    index[uy, ux] = np.arange(m)
    neighbour = np.full((m, 4), -1, np.int64)
    rhs, degree = np.zeros((m, 3)), np.zeros(m)
    for k, (dy, dx) in enumerate(((0, 1), (0, -1), (1, 0), (-1, 0))):
        ny, nx = uy + dy, ux + dx
        ok = (ny >= 0) & (ny < h) & (nx >= 0) & (nx < w)
        src, ny, nx = np.flatnonzero(ok), ny[ok], nx[ok]
        same = charts[ny, nx] == charts[uy[src], ux[src]]
        src, ny, nx = src[same], ny[same], nx[same]
        degree[src] += 1
        neighbour[src, k] = index[ny, nx]
        fixed_nb = index[ny, nx] < 0
        rhs[src[fixed_nb]] += delta[ny[fixed_nb], nx[fixed_nb]]  # pinned texels; 0 beyond the band
    if m:
        delta[uy, ux] = _harmonic(neighbour, rhs, degree, 0.01, 20 * band)
    log.info("seam blending: %d seam edges (and %d shorter than %g texels left out), %d pinned and %d band texels, "
             "mean change %.2f", len(fa), short, MIN_SEAM_TEXELS, int(fixed.sum()), m, float(np.abs(half).mean()))
    return np.clip(atlas + delta.astype(np.float32), 0, 255)
