"""Shared fixtures of the dense-stereo tests: small synthetic scenes with their dense workspaces.

Importing ``recon.mvs`` here, before any test module imports pycolmap, loads numba's compiler first
(see ``recon/mvs/__init__.py``).
"""

import pytest

from recon.mvs.bench import prepare_synthetic


@pytest.fixture(scope="session")
def small_scene(tmp_path_factory):
    """6 views at 320x240 along a line past the synthetic scene, as a dense workspace under
    ``<root>/dense`` (the rendering with its ground truth under ``<root>/scene``)."""
    root = tmp_path_factory.mktemp("mvs-small")
    prepare_synthetic(root, views=6, width=320, height=240, path="line")
    return root
