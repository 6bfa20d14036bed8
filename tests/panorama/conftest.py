"""Shared fixtures: a rendered 360 deg ring of views and its panorama (computed once per session)."""

from __future__ import annotations

import pytest

from recon.panorama import PanoramaOptions, compose, register
from recon.synth import panorama as sp


@pytest.fixture(scope="session")
def ring() -> sp.PanoramaViews:
    """12 views, 640x480, 50 deg wide (30 deg apart: 40 % overlap), jitter 1.5 deg, gains 0.85-1.15."""
    return sp.render_views(views=12, width=640, height=480, hfov_deg=50.0, seed=0)


@pytest.fixture(scope="session")
def ring_registration(ring):
    return register(ring.images, PanoramaOptions())


@pytest.fixture(scope="session")
def ring_panorama(ring, ring_registration):
    return compose(ring.images, ring_registration, PanoramaOptions())
