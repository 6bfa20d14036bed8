"""Face adjacency and patches of a triangle mesh."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


def face_adjacency(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of faces sharing an edge (E, 2) and that edge's two vertices (E, 2); an edge with more than two
    faces links consecutive ones."""
    f = np.asarray(faces, np.int64)
    edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    owner = np.tile(np.arange(len(f)), 3)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    edges, owner = edges[order], owner[order]
    same = np.all(edges[1:] == edges[:-1], axis=1)
    pairs = np.stack([owner[:-1][same], owner[1:][same]], axis=1)
    return pairs, edges[:-1][same]


def patches(labels: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """Patch id per face: connected faces (through shared edges) with the same label."""
    n = len(labels)
    same = pairs[labels[pairs[:, 0]] == labels[pairs[:, 1]]]
    graph = sp.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]
