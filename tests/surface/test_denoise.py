"""recon.surface.denoise: noise on flat faces goes, the edges between them stay as they were."""

import numpy as np
import trimesh

from recon.surface.denoise import denoised_vertices


def _box(subdivisions: int = 4) -> trimesh.Trimesh:
    """A 2 x 2 x 2 cube, each side cut into small triangles."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    for _ in range(subdivisions):
        box = box.subdivide()
    return box


def _side_normals(vertices: np.ndarray) -> np.ndarray:
    """The true normal of the cube's side each face lies on (from its centroid's largest coordinate)."""
    axis = np.argmax(np.abs(vertices), axis=1)
    normals = np.zeros_like(vertices)
    normals[np.arange(len(vertices)), axis] = np.sign(vertices[np.arange(len(vertices)), axis])
    return normals


def _angles(vertices: np.ndarray, faces: np.ndarray, truth: np.ndarray) -> np.ndarray:
    normals = trimesh.Trimesh(vertices, faces, process=False).face_normals
    return np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", normals, truth), -1, 1)))


def test_a_noisy_cube_comes_out_flat_and_its_edges_stay_as_they_were():
    box = _box()
    faces = np.asarray(box.faces)
    clean = np.asarray(box.vertices)
    truth = _side_normals(clean[faces].mean(axis=1))
    noisy = clean + np.random.default_rng(0).normal(0, 0.01, clean.shape)  # a tenth of a triangle's side
    after = denoised_vertices(noisy, faces)
    # faces off the edges (every vertex 3 or more triangles from the nearest edge): flat, as the side they lie on
    inner = (np.sort(np.abs(clean), axis=1)[:, 1] < 1 - 3 * 0.125)[faces].all(axis=1)
    assert inner.sum() > 500
    assert np.median(_angles(noisy, faces, truth)[inner]) > 5
    assert np.median(_angles(after, faces, truth)[inner]) < 1.5
    # the vertices on the cube's edges (on two of its sides) keep Poisson's shape there: not moved at all
    on_edge = np.sum(np.abs(clean) > 0.999, axis=1) >= 2
    assert on_edge.sum() > 100 and np.array_equal(after[on_edge], noisy[on_edge])


def test_noise_off_a_plane_shrinks():
    side = 41  # a 4 x 4 square of 0.1 cells, two triangles each
    x, y = np.meshgrid(np.linspace(-2, 2, side), np.linspace(-2, 2, side))
    corner = (np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None]).ravel()
    faces = np.concatenate([np.column_stack([corner, corner + 1, corner + side + 1]),
                            np.column_stack([corner, corner + side + 1, corner + side])])
    noisy = np.column_stack([x.ravel(), y.ravel(), np.random.default_rng(1).normal(0, 0.01, side * side)])
    after = denoised_vertices(noisy, faces)
    inner = np.all(np.abs(noisy[:, :2]) < 1.8, axis=1)  # away from the border, whose vertices have fewer faces
    assert np.std(after[inner, 2]) < 0.3 * np.std(noisy[inner, 2])
    assert np.abs(after[:, :2] - noisy[:, :2]).max() < 0.05  # moved across the plane, hardly along it


def test_clean_cube_stays_in_place():
    box = _box(3)
    after = denoised_vertices(box.vertices, box.faces)
    # across a right angle a neighbour's normal weighs exp(-8) of a like one, and the edges are held
    assert np.abs(after - box.vertices).max() < 1e-4
