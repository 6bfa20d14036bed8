"""Longer runs of the panorama checks (the quick ones use one 12-view ring, see conftest.py)."""

from __future__ import annotations

import numpy as np
import pano_eval as pe
import pytest

from recon.panorama import PanoramaOptions, compose, register
from recon.synth import panorama as sp


@pytest.mark.slow
@pytest.mark.parametrize("projection", ["spherical", "cylindrical"])
def test_wide_ring_matched_in_a_window(projection):
    """16 views 60 deg wide with 2 deg jitter, each matched only with its 2 next in file order,
    cyclically (the last with the first): the ring closes and all the figures hold."""
    views = sp.render_views(views=16, width=640, height=480, hfov_deg=60.0, jitter_deg=2.0, seed=7)
    opts = PanoramaOptions(projection=projection, match_window=2)
    reg = register(views.images, opts)
    assert reg.connected == list(range(16))
    assert {(0, 15), (0, 14), (1, 15)} <= {(p.i, p.j) for p in reg.pairs}
    pano = compose(views.images, reg, opts)
    assert pano.model.full_circle
    cols = pe.marker_columns(pano, views.rotations)
    seams = pe.seam_jumps(pano, pe.ground_truth(pano, views.rotations))
    print(projection, f"columns: mapped max {np.abs(cols.mapped_error).max():.2f} px, found max "
          f"{np.abs(cols.found_error).max():.2f} px, content max {cols.content_error.max():.2f}; {seams}; "
          f"timings {({**reg.timings, **pano.timings})}")
    assert np.abs(cols.mapped_error).max() < 2.0 and np.abs(cols.found_error).max() < 2.0
    assert cols.content_error.max() < 1.0
    assert seams.jump < 3.0 and seams.wrap_jump < 3.0 and seams.gain_spread < 0.02


@pytest.mark.slow
def test_focal_prior_is_refined(ring):
    """focal: prior starts from the given focal length (here 10 % off) and the bundle adjustment
    brings it to the truth."""
    f = float(ring.K[0, 0])
    opts = PanoramaOptions(focal="prior", seam="voronoi")
    reg = register(ring.images, opts, focal_priors=[1.1 * f] * len(ring.images))
    assert np.abs(reg.focals / f - 1).max() < 0.005
    pano = compose(ring.images, reg, opts)
    cols = pe.marker_columns(pano, ring.rotations)
    assert np.abs(cols.found_error).max() < 2.0 and cols.content_error.max() < 1.0
