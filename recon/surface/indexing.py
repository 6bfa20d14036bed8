"""Fast unique rows of small non-negative integer arrays (edges, faces, (patch, vertex) pairs)."""

from __future__ import annotations

import numpy as np


def row_keys(rows: np.ndarray) -> np.ndarray | None:
    """One int64 per row (mixed radix over the columns), or None when the rows are too wide to fit."""
    rows = np.asarray(rows, np.int64)
    if rows.size == 0:
        return np.zeros(len(rows), np.int64)
    base = rows.max(axis=0) + 1
    if np.prod(base.astype(float)) >= 2.0**62:
        return None
    key = np.zeros(len(rows), np.int64)
    for c in range(rows.shape[1]):
        key = key * base[c] + rows[:, c]
    return key


def unique_rows(rows: np.ndarray, return_index: bool = False, return_inverse: bool = False,
                return_counts: bool = False):
    """``np.unique(rows, axis=0, ...)`` for non-negative integer rows, by sorting one int64 key per row
    (an order of magnitude faster than ``axis=0``); results come in the same order and form."""
    rows = np.asarray(rows, np.int64)
    key = row_keys(rows)
    if key is None:
        return np.unique(rows, axis=0, return_index=return_index, return_inverse=return_inverse,
                         return_counts=return_counts)
    _, index, inverse, counts = np.unique(key, return_index=True, return_inverse=True, return_counts=True)
    out = [rows[index]]
    if return_index:
        out.append(index)
    if return_inverse:
        out.append(inverse.reshape(-1))
    if return_counts:
        out.append(counts)
    return out[0] if len(out) == 1 else tuple(out)
