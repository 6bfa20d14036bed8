"""Metric scale from scale bars: known distances between pairs of points measured in a model.

Each bar gives a ratio (its known length over its length in the model); the scale is their least-
squares fit in relative terms, so that a 0.5 m bar and a 5 m bar count alike for the same relative
error. With two bars or more their disagreement is the stated uncertainty.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class BarScale:
    scale: float  # multiply model lengths by this to get metres
    errors: np.ndarray  # (N,) per bar: (scale x model length - known length) / known length
    relative_std: float  # standard error of the scale relative to it (NaN with one bar)


def fit_scale(measured: np.ndarray, lengths: np.ndarray) -> BarScale:
    """The scale s minimising sum ((s d_i - L_i) / L_i)^2 for model lengths ``measured`` d_i (> 0) and
    known ``lengths`` L_i (> 0)."""
    d = np.asarray(measured, dtype=float).reshape(-1)
    known = np.asarray(lengths, dtype=float).reshape(-1)
    if len(d) == 0 or len(d) != len(known) or (d <= 0).any() or (known <= 0).any():
        raise ValueError("fit_scale needs paired positive lengths")
    ratio = d / known
    s = float(ratio.sum() / (ratio**2).sum())
    errors = s * ratio - 1.0
    n = len(d)
    std = float(np.sqrt((errors**2).sum() / (n - 1) / n)) if n > 1 else math.nan
    return BarScale(s, errors, std)
