"""No depth where the photos match as well at infinity: the sky, and whatever else has no parallax.

Every photo sees the sky along parallel rays, so the plane at infinity (the homography K_s R K^-1 from
the reference to a source) maps a sky pixel onto the same sky in every source, and a smooth sky matches
about as well at any far depth. PatchMatch still gives such a pixel the depth of some plane in the view's
range, the filter finds sources that agree (their own sky depths are as arbitrary, and far away a few
percent of depth is a small reprojection error), and fusion keeps the point. On the zoo's far_field (a
meadow to the horizon under a gradient sky) 1.0 % of the fused cloud was sky, 86-134 m from the cameras
and 60-85 m from any surface: accuracy at 0.2 % of the scene's extent .988 with it, .998 without.

So a final depth is dropped where the pixel's own sources (its view mask) match it no better than they
match the plane at infinity, within :data:`MARGIN` of 1 - NCC. A surface with parallax matches far
better at its depth than at infinity: its window lands where the surface is, not where the sky would
be. A surface so far away that it has none gives no depth the photos can vouch for.
"""

from __future__ import annotations

import numpy as np

from recon.mvs import patchmatch
from recon.mvs.options import MVSOptions

#: a depth must match its sources better than the plane at infinity does by more than this (1 - NCC)
MARGIN = 0.02


def matched_at_infinity(view: patchmatch.Checked, state: patchmatch.State, options: MVSOptions) -> np.ndarray:
    """Bool per pixel: it holds a depth whose matching cost (``state.cost``, the photometric cost over its
    sources in ``state.views`` that :func:`recon.mvs.patchmatch.filter_depth` kept it for) is no lower than
    what the same sources give the plane at infinity, less :data:`MARGIN` (module doc)."""
    held = state.depth > 0
    if not held.any():
        return held
    far = np.float32(1e6 * float(state.depth[held].max()))
    facing = np.zeros_like(state.normal)
    facing[..., 2] = -1.0
    # (a pixel without a depth matches no source there: its empty view mask spares the warps)
    at_infinity = patchmatch.State(np.full_like(state.depth, far), facing, np.zeros_like(state.cost),
                                   np.where(held, state.views, 0))
    return held & (patchmatch.photometric_costs(view, at_infinity, options).cost <= state.cost + MARGIN)


def drop_at_infinity(view: patchmatch.Checked, state: patchmatch.State, options: MVSOptions) -> int:
    """Zero (in place) the depths and normals of ``state`` that :func:`matched_at_infinity` finds; how many."""
    drop = matched_at_infinity(view, state, options)
    state.depth[drop] = 0.0
    state.normal[drop] = 0.0
    return int(drop.sum())
