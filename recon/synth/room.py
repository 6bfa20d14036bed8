"""A synthetic room: a closed, textured box (floor, walls, ceiling) with a few textured solids in it.

World frame: z up, the floor is the rectangle |x| <= ROOM_HALF[0], |y| <= ROOM_HALF[1] at z = 0 and
the ceiling is at z = ROOM_HEIGHT. Every surface faces into the room. Walls, floor and ceiling carry
different photographs (no repeated content: matching must not confuse two walls); the solids stand
away from the line the panoramas of :mod:`recon.synth.wide` are taken along (see :data:`WALK`).
"""

from __future__ import annotations

import functools

import numpy as np

from recon.synth.scene import Scene, assemble
from recon.synth.shapes import box, cylinder, quad, sphere
from recon.synth.textures import fit, grid_cells, ground_texture, make_texture, photo

ROOM_HALF = (3.0, 2.5)
ROOM_HEIGHT = 2.6
TEXELS_PER_METRE = 256
#: the walk the panoramas follow: from WALK[0] to WALK[1] (x, y), bending sideways by WALK_BEND metres
WALK = (np.array([-2.0, -1.2]), np.array([2.0, 1.2]))
WALK_BEND = 0.25
#: (name, RGB tint or None) of the photos on each wall, left to right as seen from inside
_WALLS = {
    "south": (("astronaut", None), ("rocket", None), ("coffee", None)),
    "east": (("hubble_deep_field", None), ("coins", (0.8, 0.9, 1.0))),
    "north": (("immunohistochemistry", None), ("motorcycle", None), ("retina", None)),
    "west": (("brick", (1.0, 0.8, 0.75)), ("camera", (1.0, 0.95, 0.8))),
}


@functools.cache
def build_room(seed: int = 0) -> Scene:
    """The room for ``seed``: the solids' sizes and yaws come from the seed, their places do not
    (they must stay clear of the walk). Cached; treat it as read-only."""
    rng = np.random.default_rng([seed, 7])
    hx, hy = ROOM_HALF
    z = np.array([0.0, 0.0, 1.0])
    corners = {"south": (hx, -hy), "east": (hx, hy), "north": (-hx, hy), "west": (-hx, -hy)}
    parts = []
    for name, photos in _WALLS.items():
        x0, y0 = corners[name]
        start = np.array([x0, y0, 0.0])
        inward = -np.sign([x0, y0, 0.0]) * ([0, 1, 0] if name in ("south", "north") else [1, 0, 0])
        along = np.cross(z, inward)  # left to right seen from inside; along x z = inward
        length = 2 * (hx if name in ("south", "north") else hy)
        parts.append(quad(f"wall_{name}", start, along * length, z * ROOM_HEIGHT,
                           make_texture(_wall_texture(photos, length))))
    floor_tex = make_texture(ground_texture(_texels(2 * hx)))
    parts.append(quad("floor", [-hx, -hy, 0.0], [2 * hx, 0, 0], [0, 2 * hy, 0], floor_tex))
    ceiling = fit(_tinted("gravel", (0.95, 0.92, 1.0)), _texels(2 * hx), _texels(2 * hy))
    parts.append(quad("ceiling", [-hx, hy, ROOM_HEIGHT], [2 * hx, 0, 0], [0, -2 * hy, 0], make_texture(ceiling)))

    cells = (256, 256)
    yaws = rng.uniform(0.0, np.pi / 2, size=2)
    parts += box("cabinet", (-1.8, 1.5), (rng.uniform(0.7, 0.9), rng.uniform(0.45, 0.6), rng.uniform(0.9, 1.2)),
                  yaws[0], grid_cells(_tinted("cell", (0.75, 0.9, 1.0)), 3, 2, cells))
    parts += box("crate", (1.7, -1.5), (rng.uniform(0.5, 0.7), rng.uniform(0.5, 0.7), rng.uniform(0.4, 0.6)),
                  yaws[1], grid_cells(photo("chelsea"), 3, 2, cells))
    radius = rng.uniform(0.3, 0.4)
    parts.append(sphere("ball", np.array([0.3, 1.7, radius]), radius,
                         make_texture(fit(_tinted("moon", (1.0, 0.85, 0.7)), 512, 320), wrap=True)))
    parts += cylinder("column", (-0.2, -1.7), rng.uniform(0.22, 0.3), rng.uniform(1.0, 1.4),
                       make_texture(fit(_tinted("page", (0.85, 0.85, 1.0)), 640, 384), wrap=True),
                       make_texture(fit(_tinted("text", (1.0, 1.0, 0.8)), 288, 288)))
    return assemble(parts)


def _texels(metres: float) -> int:
    """Texture side for ``metres`` of surface: TEXELS_PER_METRE, rounded to the mip alignment (32)."""
    return max(32, round(metres * TEXELS_PER_METRE / 32) * 32)


def _wall_texture(photos, length: float) -> np.ndarray:
    """The photos side by side across a wall of ``length`` metres, each fitted to its share."""
    width, height = _texels(length), _texels(ROOM_HEIGHT)
    edges = np.linspace(0, width, len(photos) + 1).round().astype(int)
    return np.concatenate([fit(_tinted(name, tint), int(b - a), height)
                           for (name, tint), a, b in zip(photos, edges[:-1], edges[1:], strict=True)], axis=1)


def _tinted(name: str, tint: tuple[float, float, float] | None) -> np.ndarray:
    img = photo(name)
    return img if tint is None else np.round(img * np.asarray(tint, np.float32)).astype(np.uint8)
