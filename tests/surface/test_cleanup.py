import numpy as np
import trimesh
from surface_scene import sphere_points

from recon.surface.cleanup import (
    clean_mesh,
    decimate,
    remove_degenerate_faces,
    remove_non_manifold_edges,
    remove_small_components,
    split_non_manifold_vertices,
)
from recon.surface.options import MeshOptions


def _sphere_with_junk():
    """A sphere, a far-away small tetrahedron, and three bad faces: a repeated-vertex face, a zero-area face
    on three collinear new vertices, and a duplicate of face 0."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    tet = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    tet.apply_translation((5, 0, 0))
    base = trimesh.util.concatenate([sphere, tet])
    v = np.concatenate([base.vertices, [[0, 0, 3], [0, 0, 3.5], [0, 0, 4]]])
    n = len(base.vertices)
    f = np.concatenate([base.faces, [[0, 1, 1], [n, n + 1, n + 2], base.faces[0]]])
    mesh = trimesh.Trimesh(v, f, process=False)
    mesh.visual.vertex_colors = np.tile([10, 200, 30, 255], (len(v), 1)).astype(np.uint8)
    return mesh, sphere


def test_degenerate_faces_go_and_nothing_else():
    mesh, sphere = _sphere_with_junk()
    out = remove_degenerate_faces(mesh)
    assert len(out.faces) == len(sphere.faces) + 12  # sphere + the cube's 12 faces
    assert len(out.vertices) == len(sphere.vertices) + 8  # the collinear vertices are unreferenced now


def test_floating_piece_goes():
    mesh, sphere = _sphere_with_junk()
    out = remove_small_components(remove_degenerate_faces(mesh), 0.01)
    assert len(out.faces) == len(sphere.faces)
    assert np.allclose(np.sort(out.vertices, axis=0), np.sort(sphere.vertices, axis=0))
    assert out.is_watertight
    assert (np.asarray(out.visual.vertex_colors)[:, 1] == 200).all()


def test_non_manifold_edge_keeps_two_largest_faces():
    v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0], [0.5, 0, 0.2]], float)
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])  # face 2 is the smallest on edge 0-1
    out = remove_non_manifold_edges(trimesh.Trimesh(v, f, process=False))
    assert len(out.faces) == 2
    assert np.isclose(out.area, 1.0)


def test_bowtie_vertex_is_split():
    v = np.array([[0, 0, 0], [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0]], float)
    f = np.array([[0, 1, 2], [0, 4, 3]])  # two triangles meeting only at vertex 0
    out = split_non_manifold_vertices(trimesh.Trimesh(v, f, process=False))
    assert len(out.vertices) == 6 and len(out.faces) == 2
    assert len(set(out.faces[:, 0])) == 2
    assert np.allclose(out.vertices[out.faces[0, 0]], out.vertices[out.faces[1, 0]])
    # a manifold mesh is left as it is
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert len(split_non_manifold_vertices(sphere).vertices) == len(sphere.vertices)


def test_decimate_reaches_target_and_keeps_shape():
    sphere = trimesh.creation.icosphere(subdivisions=5)
    out = decimate(sphere, 2000)
    assert len(out.faces) <= 2000 and len(out.faces) > 1500
    r = np.linalg.norm(out.vertices, axis=1)
    assert np.abs(r - 1).max() < 0.02


def test_decimate_keeps_vertex_colours_where_they_were():
    sphere = trimesh.creation.icosphere(subdivisions=5)
    top = sphere.vertices[:, 2] > 0
    sphere.visual.vertex_colors = np.where(top[:, None], [255, 0, 0, 255], [0, 0, 255, 255]).astype(np.uint8)
    out = decimate(sphere, 2000)
    colours = np.asarray(out.visual.vertex_colors)[:, :3]
    away = np.abs(out.vertices[:, 2]) > 0.05  # clear of the border between the two halves
    expected = np.where((out.vertices[:, 2] > 0)[:, None], [255, 0, 0], [0, 0, 255])
    assert away.sum() > 500
    assert np.array_equal(colours[away], expected[away])


def test_clean_mesh_pipeline():
    mesh, sphere = _sphere_with_junk()
    out = clean_mesh(mesh, MeshOptions(min_component_fraction=0.01, target_faces=0))
    assert len(out.faces) == len(sphere.faces)
    assert out.is_watertight


def test_a_piece_without_points_goes_and_a_supported_one_of_its_size_stays():
    """Two pieces apart from the main surface, each 9 % of its area: one carries points as densely as the
    main surface (a pole, a distant wall), the other a twentieth as densely (Poisson bridging stray points)."""
    pieces = [(np.zeros(3), 1.0), (np.array([3.0, 0, 0]), 0.3), (np.array([-3.0, 0, 0]), 0.3)]
    mesh = trimesh.util.concatenate([trimesh.creation.icosphere(subdivisions=3, radius=r).apply_translation(c)
                                     for c, r in pieces])
    points = np.concatenate([c + r * sphere_points(n) for (c, r), n in zip(pieces, (4000, 360, 18), strict=True)])
    assert len(remove_small_components(mesh, 0.01, points, 0.0).faces) == len(mesh.faces)
    out = remove_small_components(mesh, 0.01, points, 0.15)
    kept = out.triangles_center
    assert len(out.faces) == 2 * len(mesh.faces) // 3
    assert (kept[:, 0] > -2).all() and (kept[:, 0] > 2).any()
    # the largest piece stays whatever its support: with points on the third piece only, the second goes
    alone = remove_small_components(mesh, 0.01, points[4360:], 0.15).triangles_center
    assert (np.abs(alone[:, 0]) < 1.1).any() and (alone[:, 0] < -2).any() and not (alone[:, 0] > 2).any()
