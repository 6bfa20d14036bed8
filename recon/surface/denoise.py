"""Feature-preserving mesh denoising: bilateral filtering of the face normals (Zheng et al. 2011, "Bilateral
Normal Filtering for Mesh Denoising"), then the vertices moved to fit the filtered normals (Sun et al. 2007).

A Poisson surface follows its fused points' noise: flat faces come out bumpy and box edges ragged, which
shading shows at once. Laplacian and Taubin smoothing (open3d, trimesh) round the edges as they flatten the
faces, and cost mesh F on the zoo (docs/DECISIONS.md). The bilateral filter averages a face's normal only
with neighbours whose normals are close to it, so across an edge, where the normals differ, nothing is
mixed. Neither open3d nor trimesh has it (pymeshlab has, but is not a dependency); it is a few sparse
array operations.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse

#: filtering sweeps over the face normals, and vertex updates after them
NORMAL_SWEEPS = 5
VERTEX_SWEEPS = 10
#: range sigma on the difference of two unit normals: 0.35 (about 20 degrees) mixes the normals of a noisy
#: flat face and keeps those of two faces meeting at a sharper angle apart (a right angle weighs exp(-8))
SIGMA_NORMAL = 0.35


def _faces(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each face's unit normal (zero for a degenerate face), centroid and area."""
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    double_area = np.linalg.norm(cross, axis=1)
    normals = np.divide(cross, double_area[:, None], out=np.zeros_like(cross), where=double_area[:, None] > 0)
    return normals, (a + b + c) / 3, double_area / 2


def _face_pairs(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i, j), i != j, of faces sharing a vertex, both ways."""
    count = len(faces)
    incidence = scipy.sparse.csr_matrix((np.ones(3 * count), (np.repeat(np.arange(count), 3), faces.ravel())),
                                        shape=(count, vertex_count))
    pairs = (incidence @ incidence.T).tocoo()
    apart = pairs.row != pairs.col
    return pairs.row[apart], pairs.col[apart]


def filtered_normals(vertices: np.ndarray, faces: np.ndarray, sweeps: int = NORMAL_SWEEPS,
                     sigma_normal: float = SIGMA_NORMAL) -> np.ndarray:
    """The faces' normals after ``sweeps`` of bilateral filtering: each the area-weighted mean of its own and
    its vertex neighbours', weighted by a Gaussian of the centroids' distance (sigma: the mean distance
    between neighbours) and of the normals' difference (``sigma_normal``)."""
    normals, centroids, areas = _faces(vertices, faces)
    i, j = _face_pairs(faces, len(vertices))
    if not len(i):
        return normals
    spread = np.sum((centroids[i] - centroids[j]) ** 2, axis=1)
    spatial = areas[j] * np.exp(-spread / (2 * np.mean(np.sqrt(spread)) ** 2))
    for _ in range(sweeps):
        weight = spatial * np.exp(-np.sum((normals[i] - normals[j]) ** 2, axis=1) / (2 * sigma_normal ** 2))
        total = areas[:, None] * normals
        np.add.at(total, i, weight[:, None] * normals[j])
        length = np.linalg.norm(total, axis=1, keepdims=True)
        normals = np.divide(total, length, out=np.zeros_like(total), where=length > 0)
    return normals


def denoised_vertices(vertices: np.ndarray, faces: np.ndarray, sweeps: int = VERTEX_SWEEPS) -> np.ndarray:
    """The vertices moved so that the faces take the bilateral-filtered normals: each vertex, ``sweeps``
    times, by the mean over its faces of its offset from the face's plane (through the centroid, with the
    filtered normal), Sun et al.'s update. The connectivity is unchanged."""
    faces = np.asarray(faces, np.int64)
    moved = np.array(vertices, np.float64)
    if not len(faces):
        return moved
    normals = filtered_normals(moved, faces)
    valence = np.maximum(np.bincount(faces.ravel(), minlength=len(moved)), 1)[:, None]
    for _ in range(sweeps):
        centroids = moved[faces].mean(axis=1)
        shift = np.zeros_like(moved)
        for corner in range(3):
            offset = np.einsum("ij,ij->i", normals, centroids - moved[faces[:, corner]])
            np.add.at(shift, faces[:, corner], normals * offset[:, None])
        moved += shift / valence
    return moved
