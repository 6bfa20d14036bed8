"""Geometry of the synthetic scene: a textured ground square and a few textured solids.

World frame: z up, the ground is the square |x|, |y| <= GROUND_HALF at z = 0. The solids (two boxes,
a sphere sunk slightly into the ground, a cylinder) stand inside a disc of radius OBJECT_RADIUS
around the origin; their sizes, positions and yaw come from the seed. Each surface is a "part": a
triangle mesh with per-vertex texel coordinates into its own photographic texture and per-vertex
shading normals (smooth on the sphere and the cylinder's side, flat elsewhere). Faces that can never
be seen (bottoms resting on the ground) are left out.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from recon.synth.textures import Texture, fit, grid_cells, ground_texture, make_texture, photo

GROUND_HALF = 3.0
GROUND_TEXELS = 1536
OBJECT_RADIUS = 1.3
TARGET = np.array([0.0, 0.0, 0.35])  # the point the cameras look at
SEGMENTS = 96  # around the sphere and the cylinder


@dataclasses.dataclass(frozen=True, eq=False)
class Part:
    """One textured surface: vertices (V,3), triangles (F,3), texel coordinates (V,2) into
    ``texture``'s level 0, unit shading normals (V,3)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    texture: Texture

    @property
    def texels_per_unit(self) -> float:
        """Texel density on the surface: sqrt(texture area / world area) of the triangles."""
        tri = self.vertices[self.faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        uv = self.uv[self.faces]
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
        return float(np.sqrt(uv_area / area))


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """All parts, with their meshes concatenated for ray casting (``face_part`` maps a triangle to
    its part)."""

    parts: tuple[Part, ...]
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    face_part: np.ndarray

    @property
    def bbox(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(0), self.vertices.max(0)


@functools.cache
def build_scene(seed: int = 0) -> Scene:
    """The scene for ``seed`` (deterministic; cached, treat it as read-only)."""
    rng = np.random.default_rng([seed, 0])
    box_a = (rng.uniform(0.5, 0.8), rng.uniform(0.5, 0.8), rng.uniform(0.6, 1.0))
    box_b = (rng.uniform(0.45, 0.7), rng.uniform(0.45, 0.7), rng.uniform(0.3, 0.55))
    sphere_r = rng.uniform(0.32, 0.45)
    cyl_r, cyl_h = rng.uniform(0.22, 0.32), rng.uniform(0.6, 1.0)
    radii = [np.hypot(*box_a[:2]) / 2, np.hypot(*box_b[:2]) / 2, sphere_r, cyl_r]
    centres = _place(rng, radii)
    yaws = rng.uniform(0.0, np.pi / 2, size=2)

    cells = (256, 256)
    immuno = grid_cells(photo("immunohistochemistry"), 3, 2, cells)
    moto = grid_cells(photo("motorcycle"), 3, 2, cells)
    parts = [
        _quad("ground", [-GROUND_HALF, -GROUND_HALF, 0], [2 * GROUND_HALF, 0, 0], [0, 2 * GROUND_HALF, 0],
              make_texture(ground_texture(GROUND_TEXELS))),
        *_box("box_a", centres[0], box_a, yaws[0], immuno),
        *_box("box_b", centres[1], box_b, yaws[1], moto),
        _sphere("sphere", np.array([*centres[2], 0.85 * sphere_r]), sphere_r,
                make_texture(fit(photo("chelsea"), 512, 320), wrap=True)),
        *_cylinder("cylinder", centres[3], cyl_r, cyl_h,
                   make_texture(fit(photo("coffee"), 640, 384), wrap=True),
                   make_texture(fit(photo("coins"), 288, 288))),
    ]
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    return Scene(
        parts=tuple(parts),
        vertices=np.concatenate([p.vertices for p in parts]),
        faces=np.concatenate([p.faces + off for p, off in zip(parts, offsets, strict=False)]),
        uv=np.concatenate([p.uv for p in parts]),
        normals=np.concatenate([p.normals for p in parts]),
        face_part=np.concatenate([np.full(len(p.faces), i, np.int32) for i, p in enumerate(parts)]),
    )


def _place(rng: np.random.Generator, radii: list[float], gap: float = 0.15) -> list[np.ndarray]:
    """Centres (x, y) inside the object disc with footprints ``radii`` apart by at least ``gap``."""
    for _ in range(10000):
        centres = []
        for r in radii:
            rho = np.sqrt(rng.uniform(0, 1)) * (OBJECT_RADIUS - r)
            phi = rng.uniform(0, 2 * np.pi)
            c = np.array([rho * np.cos(phi), rho * np.sin(phi)])
            if all(np.linalg.norm(c - o) >= r + ro + gap for o, ro in zip(centres, radii, strict=False)):
                centres.append(c)
            else:
                break
        if len(centres) == len(radii):
            return centres
    raise RuntimeError("could not place the objects")


def _quad(name: str, p0, e1, e2, texture: Texture) -> Part:
    """A parallelogram p0 + a e1 + b e2 (a, b in [0, 1]), normal e1 x e2; e1 runs along the texture's
    columns, e2 up its rows."""
    p0, e1, e2 = (np.asarray(v, dtype=float) for v in (p0, e1, e2))
    w, h = texture.size
    verts = np.array([p0, p0 + e1, p0 + e1 + e2, p0 + e2])
    uv = np.array([[0, h], [w, h], [w, 0], [0, 0]], dtype=float)
    n = np.cross(e1, e2)
    normals = np.tile(n / np.linalg.norm(n), (4, 1))
    return Part(name, verts, np.array([[0, 1, 2], [0, 2, 3]]), uv, normals, texture)


def _box(name: str, centre, size, yaw: float, faces_tex: list[np.ndarray]) -> list[Part]:
    sx, sy, sz = size
    ex = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * sx
    ey = np.array([-np.sin(yaw), np.cos(yaw), 0.0]) * sy
    ez = np.array([0.0, 0.0, sz])
    b0 = np.array([centre[0], centre[1], 0.0]) - ex / 2 - ey / 2
    sides = [(b0, ex, ez), (b0 + ex, ey, ez), (b0 + ex + ey, -ex, ez), (b0 + ey, -ey, ez), (b0 + ez, ex, ey)]
    return [_quad(f"{name}_{i}", p0, e1, e2, make_texture(faces_tex[i])) for i, (p0, e1, e2) in enumerate(sides)]


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    """Two triangles per cell of a (rows+1) x (cols+1) vertex grid, row-major."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    a = (i * (cols + 1) + j).ravel()
    b, c, d = a + cols + 1, a + cols + 2, a + 1
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def _orient(vertices: np.ndarray, faces: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Drop degenerate triangles and order the rest counter-clockwise seen from outside a convex
    solid containing ``inside``."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(n, axis=1)
    faces = faces[area > 1e-12]
    n, tri = n[area > 1e-12], tri[area > 1e-12]
    flip = np.einsum("ij,ij->i", n, tri.mean(1) - inside) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def _sphere(name: str, centre: np.ndarray, r: float, texture: Texture) -> Part:
    w, h = texture.size
    lat, lon = SEGMENTS // 2, SEGMENTS
    theta, phi = np.meshgrid(np.linspace(0, np.pi, lat + 1), np.linspace(0, 2 * np.pi, lon + 1), indexing="ij")
    normals = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    uv = np.stack([phi / (2 * np.pi) * w, theta / np.pi * h], -1).reshape(-1, 2)
    verts = centre + r * normals
    return Part(name, verts, _orient(verts, _grid_faces(lat, lon), centre), uv, normals, texture)


def _cylinder(name: str, centre, r: float, height: float, side_tex: Texture, top_tex: Texture) -> list[Part]:
    n = SEGMENTS
    phi = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n + 1)])
    base = np.array([centre[0], centre[1], 0.0])
    inside = base + [0, 0, height / 2]
    up = np.array([0.0, 0.0, height])
    w, h = side_tex.size
    side_v = np.concatenate([base + r * ring + up, base + r * ring])  # top row first: texture row 0 on top
    side_uv = np.concatenate([np.column_stack([phi / (2 * np.pi) * w, np.zeros(n + 1)]),
                              np.column_stack([phi / (2 * np.pi) * w, np.full(n + 1, h)])])
    side = Part(f"{name}_side", side_v, _orient(side_v, _grid_faces(1, n), inside), side_uv,
                np.concatenate([ring, ring]), side_tex)
    tw, th = top_tex.size
    top_v = np.concatenate([[base + up], base + r * ring[:-1] + up])
    top_uv = np.concatenate([[[tw / 2, th / 2]],
                             np.column_stack([(0.5 + 0.5 * ring[:-1, 0]) * tw, (0.5 - 0.5 * ring[:-1, 1]) * th])])
    k = np.arange(n)
    top_f = np.column_stack([np.zeros(n, int), 1 + k, 1 + (k + 1) % n])
    top = Part(f"{name}_top", top_v, _orient(top_v, top_f, inside), top_uv, np.tile([0.0, 0.0, 1.0], (n + 1, 1)),
               top_tex)
    return [side, top]
