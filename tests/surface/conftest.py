"""A small synthetic scene (recon.synth) shared by the surface tests: photos, cameras, ground-truth depth
and normal maps, oriented points back-projected from them, and hold-out views."""

from __future__ import annotations

import pytest
from surface_scene import Scene, load_arrays

from recon.synth import render_scene


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory) -> Scene:
    """12 views of 320 x 240 on an orbit, and 2 hold-out views."""
    return load_arrays(render_scene(tmp_path_factory.mktemp("synth"), views=12, width=320, height=240, holdout=2))


@pytest.fixture(scope="session")
def mesh(small_scene):
    """The small scene's true surface, subdivided to edges of at most 0.1: the mesh the texture tests texture."""
    return small_scene.gt_mesh.subdivide_to_size(0.1)
