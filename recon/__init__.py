"""recon: photogrammetry from photos to cameras, dense points, meshes and textured glTF."""

from __future__ import annotations

import os
from pathlib import Path

__version__ = "0.1.0"


def run(config=None, **kwargs):
    """Run a pipeline config; see :func:`recon.api.run`."""
    from recon.api import run as _run

    return _run(config, **kwargs)


def datasets_root() -> Path:
    """Where the real photo sets with ground truth are: ``$RECON_DATASETS`` or ``../shared/datasets``."""
    env = os.environ.get("RECON_DATASETS")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "datasets"
