"""The registry of 2D preprocessing operations, and running a chain of them.

A chain is an ordered list of (operation name, options) steps, as a preprocessing config lists
them. Geometric steps update the camera and warp the mask; photometric ones leave both alone.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from recon.imaging.contrast import CLAHE, EQUALIZE, ClaheOptions
from recon.imaging.deblur import RICHARDSON_LUCY, WIENER
from recon.imaging.denoise import BILATERAL, NL_MEANS
from recon.imaging.intrinsics import Intrinsics
from recon.imaging.operation import Operation
from recon.imaging.pixels import check_image
from recon.imaging.resize import RESIZE
from recon.imaging.undistort import UNDISTORT

OPS: dict[str, Operation] = {op.name: op for op in (
    RESIZE, UNDISTORT, BILATERAL, NL_MEANS, CLAHE, EQUALIZE, WIENER, RICHARDSON_LUCY)}

Step = tuple[str, Any]  # (operation name, an instance of that operation's Options)

# Dark photos (low light, high ISO): lift local contrast. Denoising first (bilateral, range sigma from
# the measured noise) gave more correct SIFT matches on one synthetic photo 4 stops under, but worse
# poses on darkened real sets: temple_ring AUC@5 81.0 against 90.2 for CLAHE alone (noise 1.5 levels),
# 78.7 against 80.1 (noise 4); fountain_p11 99.0 with either (docs/DECISIONS.md).
LOW_LIGHT: tuple[Step, ...] = (("clahe", ClaheOptions(clip_limit=3.0)),)


def operation(name: str) -> Operation:
    try:
        return OPS[name]
    except KeyError:
        raise ValueError(f"unknown image operation {name!r}; known: {', '.join(sorted(OPS))}") from None


def apply_chain(image: np.ndarray, camera: Intrinsics | None, steps: Sequence[Step],
                mask: np.ndarray | None = None) -> tuple[np.ndarray, Intrinsics | None, np.ndarray | None]:
    """Run ``steps`` in order; returns (image, camera, mask), the mask warped by geometric steps."""
    check_image(image)
    for name, options in steps:
        op = operation(name)
        if not isinstance(options, op.Options):
            raise TypeError(f"step {name!r} needs {op.Options.__name__}, got {type(options).__name__}")
        if mask is not None and op.geometric:
            mask = op.apply_mask(mask, camera, options)
        image, camera = op.apply(image, camera, options)
    return image, camera, mask
