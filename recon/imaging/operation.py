"""The shape every 2D preprocessing operation has (the registry of them is :mod:`recon.imaging.ops`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from recon.imaging.intrinsics import Intrinsics

ApplyFn = Callable[[np.ndarray, "Intrinsics | None", Any], "tuple[np.ndarray, Intrinsics | None]"]
MaskFn = Callable[[np.ndarray, "Intrinsics | None", Any], np.ndarray]


@dataclass(frozen=True)
class Operation:
    """One named image operation with typed options.

    ``apply(image, camera, options) -> (image, camera)``: photometric operations return the camera
    unchanged; geometric ones (``geometric=True``) return the camera of the output pixels and give
    ``apply_mask(mask, camera, options) -> mask``, which warps a boolean mask (True = use) the same
    way with nearest-neighbour sampling, so masks stay aligned with their images. ``camera`` is the
    camera of the *input* image in both functions.
    """

    name: str
    Options: type
    geometric: bool
    apply: ApplyFn
    doc: str
    apply_mask: MaskFn | None = None

    def __post_init__(self) -> None:
        if self.geometric != (self.apply_mask is not None):
            raise ValueError(f"operation {self.name!r}: geometric operations, and only they, warp masks")
