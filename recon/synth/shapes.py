"""Textured surface primitives of the synthetic scenes: each is a :class:`Part` (or a list of them).

A part is a triangle mesh with per-vertex texel coordinates into its own texture and per-vertex
shading normals (smooth on curved surfaces, flat elsewhere). Two ways of texturing: a photo
stretched over a face (``quad``, ``box``, ``sphere``, ``cylinder``, ``lathe``), or a seamless
texture tiled at a fixed density in texels per metre (``tiled_quad``, ``prism``, ``heightfield``),
which keeps long walls and large grounds sharp without a huge texture. Faces that can never be seen
(bottoms resting on the ground) are left out where the caller says so.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from recon.synth.textures import Texture, make_texture

SEGMENTS = 96  # around spheres, cylinders and lathe surfaces by default
MAX_TEXEL = 30000.0  # cv2.remap turns coordinates into 16-bit integers: tiled uv must stay below this


@dataclasses.dataclass(frozen=True, eq=False)
class Part:
    """One textured surface: vertices (V,3), triangles (F,3), texel coordinates (V,2) into
    ``texture``'s level 0, unit shading normals (V,3); ``gloss``, the strength of a white specular
    highlight (0: matte; recon.synth.render)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    normals: np.ndarray
    texture: Texture
    gloss: float = 0.0

    @property
    def texels_per_unit(self) -> float:
        """Texel density on the surface: sqrt(texture area / world area) of the triangles."""
        tri = self.vertices[self.faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
        uv = self.uv[self.faces]
        e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
        uv_area = 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum()
        return float(np.sqrt(uv_area / area))


def quad(name: str, p0, e1, e2, texture: Texture) -> Part:
    """A parallelogram p0 + a e1 + b e2 (a, b in [0, 1]), normal e1 x e2; e1 runs along the texture's
    columns, e2 up its rows."""
    p0, e1, e2 = (np.asarray(v, dtype=float) for v in (p0, e1, e2))
    w, h = texture.size
    verts = np.array([p0, p0 + e1, p0 + e1 + e2, p0 + e2])
    uv = np.array([[0, h], [w, h], [w, 0], [0, 0]], dtype=float)
    n = np.cross(e1, e2)
    normals = np.tile(n / np.linalg.norm(n), (4, 1))
    return Part(name, verts, np.array([[0, 1, 2], [0, 2, 3]]), uv, normals, texture)


def tiled_quad(name: str, p0, e1, e2, texture: Texture, texels_per_unit: float) -> Part:
    """A parallelogram as :func:`quad`, with a wrapping texture tiled at ``texels_per_unit``."""
    part = quad(name, p0, e1, e2, texture)
    uv = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float) * [np.linalg.norm(e1), np.linalg.norm(e2)]
    return dataclasses.replace(part, uv=_checked(uv * texels_per_unit))


def box(name: str, centre, size, yaw: float, faces_tex: list[np.ndarray]) -> list[Part]:
    """A box standing on z = centre's ground (no bottom), ``yaw`` about z; ``faces_tex``: five images
    (four sides, then the top), each stretched over its face."""
    sx, sy, sz = size
    ex = np.array([np.cos(yaw), np.sin(yaw), 0.0]) * sx
    ey = np.array([-np.sin(yaw), np.cos(yaw), 0.0]) * sy
    ez = np.array([0.0, 0.0, sz])
    b0 = np.array([centre[0], centre[1], centre[2] if len(centre) > 2 else 0.0]) - ex / 2 - ey / 2
    sides = [(b0, ex, ez), (b0 + ex, ey, ez), (b0 + ex + ey, -ex, ez), (b0 + ey, -ey, ez), (b0 + ez, ex, ey)]
    return [quad(f"{name}_{i}", p0, e1, e2, make_texture(faces_tex[i])) for i, (p0, e1, e2) in enumerate(sides)]


def grid_faces(rows: int, cols: int) -> np.ndarray:
    """Two triangles per cell of a (rows+1) x (cols+1) vertex grid, row-major."""
    i, j = np.meshgrid(np.arange(rows), np.arange(cols), indexing="ij")
    a = (i * (cols + 1) + j).ravel()
    b, c, d = a + cols + 1, a + cols + 2, a + 1
    return np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])


def orient(vertices: np.ndarray, faces: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Drop degenerate triangles and order the rest counter-clockwise seen from outside a convex
    solid containing ``inside``."""
    tri = vertices[faces]
    return _facing(vertices, faces, tri.mean(1) - inside)


def _facing(vertices: np.ndarray, faces: np.ndarray, outward: np.ndarray) -> np.ndarray:
    """Drop degenerate triangles and order the rest counter-clockwise seen from the side ``outward``
    (one vector per face) points to."""
    tri = vertices[faces]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    keep = np.linalg.norm(n, axis=1) > 1e-12
    faces, n, outward = faces[keep].copy(), n[keep], outward[keep]
    flip = np.einsum("ij,ij->i", n, outward) < 0
    faces[flip] = faces[flip][:, ::-1]
    return faces


def sphere(name: str, centre: np.ndarray, r: float, texture: Texture, segments: int = SEGMENTS) -> Part:
    w, h = texture.size
    lat, lon = segments // 2, segments
    theta, phi = np.meshgrid(np.linspace(0, np.pi, lat + 1), np.linspace(0, 2 * np.pi, lon + 1), indexing="ij")
    normals = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1).reshape(-1, 3)
    uv = np.stack([phi / (2 * np.pi) * w, theta / np.pi * h], -1).reshape(-1, 2)
    verts = np.asarray(centre, float) + r * normals
    return Part(name, verts, orient(verts, grid_faces(lat, lon), centre), uv, normals, texture)


def cylinder(name: str, centre, r: float, height: float, side_tex: Texture, top_tex: Texture,
             segments: int = SEGMENTS) -> list[Part]:
    """An upright cylinder standing on the ground at ``centre`` (x, y[, z]) with a top cap, no bottom."""
    n = segments
    phi = np.linspace(0, 2 * np.pi, n + 1)
    ring = np.column_stack([np.cos(phi), np.sin(phi), np.zeros(n + 1)])
    base = np.array([centre[0], centre[1], centre[2] if len(centre) > 2 else 0.0])
    inside = base + [0, 0, height / 2]
    up = np.array([0.0, 0.0, height])
    w, h = side_tex.size
    side_v = np.concatenate([base + r * ring + up, base + r * ring])  # top row first: texture row 0 on top
    side_uv = np.concatenate([np.column_stack([phi / (2 * np.pi) * w, np.zeros(n + 1)]),
                              np.column_stack([phi / (2 * np.pi) * w, np.full(n + 1, h)])])
    side = Part(f"{name}_side", side_v, orient(side_v, grid_faces(1, n), inside), side_uv,
                np.concatenate([ring, ring]), side_tex)
    tw, th = top_tex.size
    top_v = np.concatenate([[base + up], base + r * ring[:-1] + up])
    top_uv = np.concatenate([[[tw / 2, th / 2]],
                             np.column_stack([(0.5 + 0.5 * ring[:-1, 0]) * tw, (0.5 - 0.5 * ring[:-1, 1]) * th])])
    k = np.arange(n)
    top_f = np.column_stack([np.zeros(n, int), 1 + k, 1 + (k + 1) % n])
    top = Part(f"{name}_top", top_v, orient(top_v, top_f, inside), top_uv, np.tile([0.0, 0.0, 1.0], (n + 1, 1)),
               top_tex)
    return [side, top]


def lathe(name: str, centre, profile, texture: Texture, segments: int = SEGMENTS) -> Part:
    """A surface of revolution about the vertical axis through ``centre``: ``profile`` is (radius, z)
    from bottom to top (radius 0 at an end closes it); concave profiles (a vase's neck) are allowed.
    The texture wraps once around and runs down the profile by arc length; normals are smooth."""
    prof = np.asarray(profile, float)
    r, z = prof[:, 0], prof[:, 1]
    seg = np.diff(prof, axis=0)
    # outward normal of each profile segment in the (r, z) plane, averaged at the vertices
    seg_n = np.column_stack([seg[:, 1], -seg[:, 0]]) / np.linalg.norm(seg, axis=1, keepdims=True)
    vert_n = np.concatenate([seg_n[:1], seg_n[:-1] + seg_n[1:], seg_n[-1:]])
    vert_n /= np.linalg.norm(vert_n, axis=1, keepdims=True)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    w, h = texture.size
    phi = np.linspace(0, 2 * np.pi, segments + 1)
    rows = len(prof) - 1
    ii, pp = np.meshgrid(np.arange(len(prof))[::-1], phi, indexing="ij")  # top row first
    c, s = np.cos(pp), np.sin(pp)
    verts = np.stack([r[ii] * c, r[ii] * s, z[ii]], -1).reshape(-1, 3) + np.asarray(centre, float)
    normals = np.stack([vert_n[ii, 0] * c, vert_n[ii, 0] * s, vert_n[ii, 1]], -1).reshape(-1, 3)
    uv = np.stack([pp / (2 * np.pi) * w, (arc[-1] - arc[ii]) / arc[-1] * h], -1).reshape(-1, 2)
    faces = grid_faces(rows, segments)
    return Part(name, verts, _facing(verts, faces, normals[faces].sum(1)), uv, normals, texture)


def prism(name: str, polygon, origin, e1, e2, depth: float, wall: Texture, cap: Texture, texels_per_unit: float,
          caps: tuple[bool, bool] = (False, True)) -> list[Part]:
    """A simple polygon (N, 2; convex or not) in the plane origin + a e1 + b e2 (e1, e2 orthonormal),
    extruded by ``depth`` along e1 x e2: a building footprint extruded up, a staircase profile
    extruded sideways. Walls (one flat face per polygon edge, sharp corners) and the caps
    (``caps``: (start, end) of the extrusion) are tiled at ``texels_per_unit``."""
    poly = np.asarray(polygon, float)
    if _signed_area(poly) < 0:
        poly = poly[::-1]
    origin, e1, e2 = (np.asarray(v, float) for v in (origin, e1, e2))
    n = np.cross(e1, e2)
    lift = n * depth

    def world(p2):
        return origin + p2[:, :1] * e1 + p2[:, 1:2] * e2

    ring = world(poly)
    nxt = np.roll(ring, -1, axis=0)
    edge = nxt - ring
    length = np.linalg.norm(edge, axis=1)
    start = np.concatenate([[0.0], np.cumsum(length)[:-1]])
    k = len(poly)
    verts = np.concatenate([ring + lift, nxt + lift, nxt, ring])  # per edge: top-left, top-right, ...
    idx = np.arange(k)
    quads = np.column_stack([idx, idx + k, idx + 2 * k, idx + 3 * k])
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    out_dir = np.cross(edge, n)  # outward for a counter-clockwise polygon
    out_dir /= np.linalg.norm(out_dir, axis=1, keepdims=True)
    uv = np.concatenate([np.column_stack([start, np.zeros(k)]), np.column_stack([start + length, np.zeros(k)]),
                         np.column_stack([start + length, np.full(k, depth)]),
                         np.column_stack([start, np.full(k, depth)])]) * texels_per_unit
    normals = np.tile(out_dir, (4, 1))
    face_out = np.concatenate([out_dir, out_dir])
    parts = [Part(f"{name}_walls", verts, _facing(verts, faces, face_out), _checked(uv), normals, wall)]
    tris = triangulate(poly)
    for which, (wanted, offset, sign) in enumerate(zip(caps, (0.0, 1.0), (-1.0, 1.0), strict=True)):
        if not wanted:
            continue
        cv = ring + lift * offset
        cap_uv = np.column_stack([poly[:, 0], -poly[:, 1]]) * texels_per_unit
        cap_uv -= np.floor(cap_uv.min(0) / cap.size) * cap.size  # non-negative, same tiling
        parts.append(Part(f"{name}_{('start', 'end')[which]}", cv, _facing(cv, tris, np.tile(sign * n, (len(tris), 1))),
                          _checked(cap_uv), np.tile(sign * n, (k, 1)), cap))
    return parts


def heightfield(name: str, x_range, y_range, cells: tuple[int, int], height: Callable[[np.ndarray, np.ndarray],
                np.ndarray], texture: Texture, texels_per_unit: float) -> Part:
    """Terrain z = height(x, y) over a rectangle, ``cells`` (nx, ny) grid cells, tiled texture,
    normals from the height's finite differences."""
    nx, ny = cells
    xs = np.linspace(*x_range, nx + 1)
    ys = np.linspace(*y_range, ny + 1)
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    zz = height(xx, yy)
    gy, gx = np.gradient(zz, ys, xs)
    normals = np.stack([-gx, -gy, np.ones_like(zz)], -1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    verts = np.stack([xx, yy, zz], -1).reshape(-1, 3)
    uv = np.column_stack([verts[:, 0] - x_range[0], y_range[1] - verts[:, 1]]) * texels_per_unit
    faces = grid_faces(ny, nx)
    return Part(name, verts, _facing(verts, faces, np.tile([0.0, 0.0, 1.0], (len(faces), 1))), _checked(uv),
                normals, texture)


def triangulate(polygon: np.ndarray) -> np.ndarray:
    """Ear-clipping triangulation of a simple counter-clockwise polygon (N, 2): (N-2, 3) indices."""
    p = np.asarray(polygon, float)
    left = list(range(len(p)))
    tris = []
    while len(left) > 3:
        for k in range(len(left)):
            a, b, c = left[k - 1], left[k], left[(k + 1) % len(left)]
            if _cross2(p[b] - p[a], p[c] - p[b]) <= 1e-12:
                continue  # reflex or straight corner: not an ear
            others = [i for i in left if i not in (a, b, c) and not any(np.allclose(p[i], p[j]) for j in (a, b, c))]
            if others and _in_triangle(p[others], p[a], p[b], p[c]).any():
                continue
            tris.append((a, b, c))
            left.pop(k)
            break
        else:
            raise ValueError("triangulate: not a simple counter-clockwise polygon")
    tris.append(tuple(left))
    return np.array(tris)


def _cross2(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _in_triangle(pts: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Points inside or on the counter-clockwise triangle abc."""
    def side(p0, p1):
        return (p1[0] - p0[0]) * (pts[:, 1] - p0[1]) - (p1[1] - p0[1]) * (pts[:, 0] - p0[0])

    eps = -1e-12
    return (side(a, b) >= eps) & (side(b, c) >= eps) & (side(c, a) >= eps)


def _signed_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _checked(uv: np.ndarray) -> np.ndarray:
    if np.abs(uv).max() >= MAX_TEXEL:
        raise ValueError(f"texel coordinates up to {np.abs(uv).max():.0f}: lower the tiling density")
    return uv
