"""Fixtures of the stereo tests: rendered pairs of the synthetic scene, each rendered once."""

from __future__ import annotations

import pytest
from stereo_pairs import BASELINE, RenderedPair, make_pair


@pytest.fixture(scope="session")
def renderer():
    from recon.synth.render import Renderer
    from recon.synth.scene import build_scene

    return Renderer(build_scene(0))


@pytest.fixture(scope="session")
def render_pair(renderer):
    """``render_pair(offset, rotation_deg)``: :func:`stereo_pairs.make_pair`, cached per arguments."""
    cache: dict = {}

    def render(offset=(BASELINE, 0.0, 0.0), rotation_deg=(0.0, 0.0, 0.0)) -> RenderedPair:
        key = (tuple(offset), tuple(rotation_deg))
        if key not in cache:
            cache[key] = make_pair(renderer, offset, rotation_deg)
        return cache[key]

    return render
