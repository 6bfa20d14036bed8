"""recon.surface.denoise: noise on flat faces goes, the edges between them stay sharp."""

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


def test_noisy_cube_comes_out_flat_with_sharp_edges():
    box = _box()
    faces = np.asarray(box.faces)
    clean = np.asarray(box.vertices)
    truth = _side_normals(clean[faces].mean(axis=1))
    noisy = clean + np.random.default_rng(0).normal(0, 0.01, clean.shape)  # a tenth of a triangle's side
    before = _angles(noisy, faces, truth)
    after = _angles(denoised_vertices(noisy, faces), faces, truth)
    assert np.median(before) > 5
    assert np.median(after) < 1.5
    # the faces along the cube's edges (a vertex on two sides) keep their side's normal: not rounded off
    on_edge = (np.sum(np.abs(clean) > 0.999, axis=1) >= 2)[faces].any(axis=1)
    assert on_edge.sum() > 100
    assert np.percentile(after[on_edge], 90) < 5


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
    # across a right angle a neighbour's normal weighs exp(-8) of a like one: the corners move 0.01 % of the side
    assert np.abs(after - box.vertices).max() < 1e-3
