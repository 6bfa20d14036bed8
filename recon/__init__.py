"""recon: photogrammetry from photos to cameras, dense points, meshes and textured glTF."""

from __future__ import annotations

import os
from pathlib import Path

# numba's compiler must be loaded before pycolmap (see recon/mvs/__init__.py): every entry point
# imports this package first, so this keeps the order right wherever pycolmap is imported later.
import llvmlite.binding  # noqa: F401

__version__ = "0.1.0"


def run(config=None, **kwargs):
    """Run a pipeline config; see :func:`recon.api.run`."""
    from recon.api import run as _run

    return _run(config, **kwargs)


def datasets_root() -> Path:
    """Where the real photo sets with ground truth are: ``$RECON_DATASETS`` or ``../shared/datasets``."""
    env = os.environ.get("RECON_DATASETS")
    return Path(env) if env else Path(__file__).resolve().parents[2] / "shared" / "datasets"
