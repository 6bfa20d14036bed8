"""Geometry of the synthetic scene: a textured ground square and a few textured solids.

World frame: z up, the ground is the square |x|, |y| <= GROUND_HALF at z = 0. The solids (two boxes,
a sphere sunk slightly into the ground, a cylinder) stand inside a disc of radius OBJECT_RADIUS
around the origin; their sizes, positions and yaw come from the seed. Each surface is a
:class:`~recon.synth.shapes.Part`; :func:`assemble` joins parts into a :class:`Scene` (the zoo's
scenes are assembled the same way, see recon.synth.zoo).
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from recon.synth.shapes import Part, box, cylinder, quad, sphere
from recon.synth.textures import fit, grid_cells, ground_texture, make_texture, photo

GROUND_HALF = 3.0
GROUND_TEXELS = 1536
OBJECT_RADIUS = 1.3
TARGET = np.array([0.0, 0.0, 0.35])  # the point the cameras look at


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
        quad("ground", [-GROUND_HALF, -GROUND_HALF, 0], [2 * GROUND_HALF, 0, 0], [0, 2 * GROUND_HALF, 0],
             make_texture(ground_texture(GROUND_TEXELS))),
        *box("box_a", centres[0], box_a, yaws[0], immuno),
        *box("box_b", centres[1], box_b, yaws[1], moto),
        sphere("sphere", np.array([*centres[2], 0.85 * sphere_r]), sphere_r,
               make_texture(fit(photo("chelsea"), 512, 320), wrap=True)),
        *cylinder("cylinder", centres[3], cyl_r, cyl_h,
                  make_texture(fit(photo("coffee"), 640, 384), wrap=True),
                  make_texture(fit(photo("coins"), 288, 288))),
    ]
    return assemble(parts)


def assemble(parts: list[Part]) -> Scene:
    """The scene made of ``parts``, their meshes concatenated in order."""
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
