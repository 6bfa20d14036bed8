"""The zoo's scenes: one builder per scene, each giving its parts, camera layout and capture.

Units are metres, z up. Texture densities (texels per metre) are set for about two texels per
pixel at 640x480 from the cameras' distance, so the mip-mapped lookups stay sharp and alias-free.
Geometry and textures are fixed per scene (their own seeded generator); the render's seed moves
only the cameras' jitter and the photo effects. A ground (or any surface photos see from opposite
sides) gets a texture large enough not to repeat across it: a tiled one makes different places look
alike, and the false matches between them broke the mapper on three scenes (plain_boxes: 41 % of the
verified matches false, cameras 50 degrees off; tests/synth/test_zoo_false_pairs.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from recon.synth.effects import Effects
from recon.synth.layouts import Around, Grid, Layout, Orbit, Walk
from recon.synth.procedural import bricks, mottled, noise, patchwork, planks, plaster, tiles, to_rgb, windows
from recon.synth.render import SKY, Background, gradient_sky
from recon.synth.scene import TARGET, build_scene
from recon.synth.shapes import Part, cylinder, heightfield, lathe, prism, sphere, tiled_quad
from recon.synth.textures import Texture, fit, grid_cells, make_texture, photo

BLACK = np.zeros(3, np.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class Setup:
    """Everything a zoo scene is made of (see recon.synth.dataset.Capture for the capture fields)."""

    parts: list[Part]
    layout: Layout
    views: int = 24
    holdout: int = 4
    focal_factor: float = 0.9
    background: Background = dataclasses.field(default_factory=lambda: SKY)
    effects: Effects | None = None
    jpeg_quality: int = 95
    transient: tuple[Part, ...] = ()
    transient_span: tuple[float, float] = (0.0, 0.0)  # share of the path (start, end) where it stands
    masked: frozenset[str] = frozenset()
    gps_sigma: float = 0.0  # > 0: GPS tags in the photos' EXIF, this many metres off per axis (recon.synth.geotags)
    radial: tuple[float, float] = (0.0, 0.0)  # the lens's distortion (k1, k2; recon.eval.groundtruth.Camera)


# ---------------------------------------------------------------------------------------------
# helpers


def tex(image: np.ndarray, wrap: bool = True) -> Texture:
    return make_texture(image, wrap=wrap)


def photo_tex(name: str, width: int, height: int, wrap: bool = True, tint=(1.0, 1.0, 1.0)) -> Texture:
    img = fit(photo(name), width, height).astype(np.float32) * np.asarray(tint, np.float32)
    return tex(to_rgb(img), wrap)


def ground(name: str, half: float, texture: Texture, density: float, centre=(0.0, 0.0)) -> Part:
    return tiled_quad(name, [centre[0] - half, centre[1] - half, 0.0], [2 * half, 0, 0], [0, 2 * half, 0],
                      texture, density)


def rect(sx: float, sy: float, yaw: float = 0.0, centre=(0.0, 0.0)) -> np.ndarray:
    """The corners of an sx x sy rectangle turned by ``yaw`` about ``centre`` (counter-clockwise)."""
    corners = np.array([[-sx, -sy], [sx, -sy], [sx, sy], [-sx, sy]]) / 2
    c, s = np.cos(yaw), np.sin(yaw)
    return corners @ np.array([[c, s], [-s, c]]) + centre


def block(name: str, footprint: np.ndarray, z0: float, height: float, wall: Texture, cap: Texture,
          density: float) -> list[Part]:
    """A footprint polygon extruded up from ``z0`` (walls and a roof, no bottom)."""
    return prism(name, footprint, [0, 0, z0], [1, 0, 0], [0, 1, 0], height, wall, cap, density)


def sideways(name: str, profile, base, yaw: float, width: float, wall: Texture, cap: Texture,
             density: float) -> list[Part]:
    """A profile (u across, z up; u along the direction ``yaw``) extruded ``width`` sideways, centred on
    ``base``: stairs, gable roofs, wheels. Both ends closed."""
    e1 = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    e2 = np.array([0.0, 0.0, 1.0])
    n = np.cross(e1, e2)
    return prism(name, profile, np.asarray(base, float) - n * width / 2, e1, e2, width, wall, cap, density,
                 caps=(True, True))


def staircase(steps: int, rise: float, run: float) -> np.ndarray:
    """Side profile (u, z) of a flight of ``steps`` steps starting at u = 0, ending in a landing."""
    pts = [(0.0, 0.0)]
    for k in range(steps):
        pts += [(k * run, (k + 1) * rise), ((k + 1) * run, (k + 1) * rise)]
    pts += [(steps * run, 0.0)]
    return np.array(pts)


def octagon(r: float, centre=(0.0, 0.0)) -> np.ndarray:
    a = np.arange(8) * np.pi / 4 + np.pi / 8
    return np.column_stack([np.cos(a), np.sin(a)]) * r + centre


def gable_house(name: str, centre, size, yaw: float, wall: Texture, roof: Texture, density: float,
                rise: float) -> list[Part]:
    """A house: a box of ``size`` (sx, sy, wall height) with a gable roof of ``rise`` over its sx side."""
    sx, sy, sz = size
    body = block(f"{name}_body", rect(sx, sy, yaw, centre[:2]), centre[2], sz, wall, wall, density)
    gable = np.array([[-sx / 2 - 0.3, 0.0], [sx / 2 + 0.3, 0.0], [0.0, rise]])
    base = [centre[0], centre[1], centre[2] + sz]
    roof_parts = sideways(f"{name}_roof", gable, base, yaw, sy + 0.4, roof, wall, density)
    return body + roof_parts


#: photos seen through (or reflected in) windows: each pane a crop of one, so no two windows look alike
BEHIND_WINDOWS = ("astronaut", "coffee", "chelsea", "rocket", "hubble_deep_field", "immunohistochemistry", "page",
                  "text", "clock", "coins", "camera", "cell", "retina", "motorcycle", "cat", "colorwheel")


def lived_in_windows(wall: np.ndarray, cell, pane, rng: np.random.Generator) -> np.ndarray:
    """:func:`recon.synth.procedural.windows` with each pane showing a darkened crop of a photo
    (curtains, rooms, reflections) instead of the same glass in every window: a grid of identical
    windows lets SIFT match one window to another, and such false pairs (hundreds of inliers between
    opposite ends of a facade) break any mapper, which is not what a real facade does."""
    height, width = wall.shape[:2]
    img = windows(width, height, rng, wall, cell, pane).astype(np.float32)
    (cw, ch), (pw, ph) = cell, pane
    sources = [fit(photo(name), 384, 288) for name in BEHIND_WINDOWS]
    for y0 in range(0, height - ch + 1, ch):  # the panes where procedural.windows puts them
        for x0 in range(0, width - cw + 1, cw):
            x1, y1 = x0 + (cw - pw) // 2, y0 + (ch - ph) // 2
            source = sources[rng.integers(len(sources))]
            u, v = rng.integers(0, 384 - pw), rng.integers(0, 288 - ph)
            img[y1 : y1 + ph, x1 : x1 + pw] = source[v : v + ph, u : u + pw] * np.float32([0.5, 0.55, 0.62])
    return to_rgb(img)


# ---------------------------------------------------------------------------------------------
# the scenes


def classic(rng: np.random.Generator) -> Setup:
    return Setup(list(build_scene(0).parts), Orbit(tuple(TARGET), 3.5, 30.0))


def courtyard(rng: np.random.Generator) -> Setup:
    d = 160.0
    brick = photo_tex("brick", 512, 512, tint=(1.05, 0.82, 0.66))
    plaster_cap = tex(mottled(256, 256, [(196, 190, 176), (150, 146, 138)], rng, 0.3))
    # 1600 texels: the 10 m ground without a repeat (repeats matched photos of different places)
    paving = tex(tiles(1600, 1600, rng, 64, [(150, 140, 128), (120, 116, 110), (170, 160, 140)], spread=0.08))
    stone = photo_tex("moon", 256, 256, tint=(1.0, 0.97, 0.9))
    u_shape = np.array([[-2.0, 0.0], [-1.2, 0.0], [-1.2, 1.0], [1.2, 1.0], [1.2, 0.0], [2.0, 0.0], [2.0, 1.8],
                        [-2.0, 1.8]])
    l_wall = np.array([[0.6, -1.9], [2.2, -1.9], [2.2, -0.7], [1.9, -0.7], [1.9, -1.6], [0.6, -1.6]])
    notched = np.array([[-2.3, -2.0], [-0.9, -2.0], [-0.9, -1.4], [-1.4, -1.4], [-1.4, -0.9], [-2.3, -0.9]])
    parts = [ground("ground", 5.0, paving, d),
             *block("u_building", u_shape, 0.0, 1.6, brick, plaster_cap, d),
             *block("l_wall", l_wall, 0.0, 0.7, brick, plaster_cap, d),
             *block("notched", notched, 0.0, 1.0, stone, plaster_cap, d),
             *sideways("stairs", staircase(4, 0.15, 0.25), [0.0, 0.0, 0.0], np.pi / 2, 1.0, stone, stone, d)]
    return Setup(parts, Orbit((0.0, 0.0, 0.5), 6.5, 35.0, arc_deg=200.0, start_deg=-190.0),
                 background=gradient_sky)


def plain_boxes(rng: np.random.Generator) -> Setup:
    d = 200.0
    # 1536 texels: the 7 m floor without a repeat (a tiled 512 made every pair of opposite photos match)
    concrete = tex(mottled(1536, 1536, [(150, 148, 142), (118, 116, 112)], rng, 0.12, beta=0.9))
    colours = [(205, 196, 178), (168, 188, 206), (214, 204, 160), (186, 160, 150)]
    flat = [tex(plaster(256, 256, c, 1.2, rng)) for c in colours]
    stained = tex(plaster(256, 256, (190, 178, 160), 5.0, rng, beta=1.8))
    parts = [ground("ground", 3.5, concrete, d),
             *block("box_a", rect(0.8, 0.6, 0.3, (-0.7, 0.4)), 0.0, 0.9, flat[0], flat[1], d),
             *block("box_b", rect(0.6, 0.6, -0.2, (0.6, 0.5)), 0.0, 0.5, flat[2], flat[3], d),
             *block("box_c", rect(1.0, 0.4, 0.1, (0.2, -0.7)), 0.0, 0.6, stained, flat[0], d),
             *cylinder("drum", (-0.5, -0.6), 0.25, 0.7, flat[3], flat[2]),
             sphere("ball", np.array([1.1, -0.3, 0.25]), 0.25, flat[1])]
    return Setup(parts, Orbit((0.0, 0.0, 0.35), 4.0, 30.0), background=np.array([0.8, 0.82, 0.85], np.float32))


def turntable_black(rng: np.random.Generator) -> Setup:
    # once round the pedestal (2 m at 600 texels/m): a tiled 256 gave its four sides one look
    marble = np.clip(np.abs(noise(1280, 512, rng, 1.3)) * 40, 0, 80)
    marble_tex = tex(to_rgb(np.array([226, 222, 214], np.float32) - marble[..., None] * [1.0, 1.0, 0.9]))
    vase = [(0.0, 0.8), (0.16, 0.8), (0.2, 0.86), (0.24, 0.98), (0.22, 1.1), (0.12, 1.22), (0.09, 1.3),
            (0.12, 1.38), (0.0, 1.38)]
    parts = [*block("pedestal", rect(0.5, 0.5), 0.0, 0.8, marble_tex, marble_tex, 600.0),
             lathe("vase", (0.0, 0.0, 0.0), vase, photo_tex("astronaut", 512, 256)),
             sphere("apple", np.array([0.17, -0.12, 0.85]), 0.05, photo_tex("retina", 128, 64), segments=48)]
    return Setup(parts, Orbit((0.0, 0.0, 1.0), 2.0, 28.0), background=BLACK)


def far_field(rng: np.random.Generator) -> Setup:
    meadow = tex(mottled(1024, 1024, [(104, 128, 66), (140, 124, 88)], rng, 0.35, beta=0.8))
    wood = tex(planks(256, 256, rng, (128, 96, 66), 48))
    roof = tex(tiles(256, 256, rng, 32, [(120, 60, 48), (100, 52, 44)], grout=2))
    rock = tex(mottled(256, 128, [(130, 126, 120), (96, 92, 88)], rng, 0.35, beta=0.9))
    barrel = photo_tex("rocket", 256, 128, tint=(0.9, 0.9, 1.0))
    parts = [ground("ground", 40.0, meadow, 80.0),
             *gable_house("shed", (0.0, 0.6, 0.0), (2.0, 1.4, 1.6), 0.2, wood, roof, 120.0, 0.7),
             sphere("rock", np.array([1.8, -1.0, 0.1]), 0.45, rock, segments=32),
             *cylinder("barrel_a", (-1.6, -0.6), 0.3, 0.9, barrel, wood),
             *cylinder("barrel_b", (-1.0, -1.2), 0.3, 0.9, barrel, wood)]
    return Setup(parts, Orbit((0.0, 0.0, 0.8), 7.0, 12.0, arc_deg=180.0, start_deg=-170.0),
                 background=gradient_sky)


def fence_poles(rng: np.random.Generator) -> Setup:
    d = 300.0
    dirt = tex(mottled(1088, 1088, [(122, 104, 80), (96, 110, 70)], rng, 0.3, beta=0.9))  # 7 m, no repeat
    post = tex(planks(128, 128, rng, (118, 84, 56), 32))
    rust = tex(mottled(128, 128, [(150, 84, 46), (90, 84, 80)], rng, 0.3, beta=0.8))
    wall = tex(bricks(512, 256, rng, (64, 32), 3, (170, 150, 120), 0.15))
    parts = [ground("ground", 3.5, dirt, 150.0),
             tiled_quad("backwall", [-3.0, 2.0, 0.0], [6.0, 0, 0], [0, 0, 1.2], wall, 150.0)]
    for k, x in enumerate(np.arange(-1.8, 1.81, 0.6)):
        parts += block(f"post_{k}", rect(0.06, 0.06, 0.0, (x, 0.0)), 0.0, 1.0, post, post, d)
    for k, z in enumerate((0.45, 0.9)):
        parts += sideways(f"rail_{k}", rect(0.04, 0.04, 0.0, (0.0, z)), (0.0, 0.0, 0.0), np.pi / 2, 3.8, rust, rust,
                          d)
    for k, (x, y) in enumerate(((-1.2, -1.2), (1.0, -0.9), (0.2, 1.0))):
        parts += cylinder(f"pole_{k}", (x, y), 0.03, 2.0, rust, rust, segments=16)
    parts += block("lamp", rect(0.2, 0.2, 0.0, (0.2, 1.0)), 2.0, 0.15, rust, rust, d)
    for k in range(4):
        parts += sideways(f"slat_{k}", rect(0.08, 0.03, 0.0, (-1.6 + k * 0.1, 0.45)), (0.0, -1.8, 0.0), 0.0, 1.4,
                          post, post, d)
    return Setup(parts, Orbit((0.0, 0.0, 0.6), 4.5, 25.0), background=gradient_sky)


def clutter(rng: np.random.Generator) -> Setup:
    floor = tex(tiles(1024, 1024, rng, 64, [(170, 60, 50), (60, 110, 150), (210, 190, 90), (70, 140, 80)],  # 5 m
                      spread=0.06))
    sources = [grid_cells(photo(n), 2, 2, (128, 128)) for n in ("text", "clock", "colorwheel", "page", "coins",
                                                                 "logo", "hubble_deep_field")]
    looks = [c for cells in sources for c in cells]
    parts = [ground("ground", 2.5, floor, 200.0)]
    placed: list[tuple[np.ndarray, float]] = []
    for _ in range(20000):
        if len(placed) == 26:
            break
        r = rng.uniform(0.1, 0.28)
        c = rng.uniform(-1.3, 1.3, 2)
        if np.linalg.norm(c) > 1.45 or any(np.linalg.norm(c - o) < r + ro + 0.03 for o, ro in placed):
            continue
        k = len(placed)
        placed.append((c, r))
        look = tex(looks[k % len(looks)])
        kind = k % 3
        if kind == 0:
            parts += block(f"crate_{k}", rect(1.3 * r, 1.3 * r, rng.uniform(0, np.pi), c), 0.0,
                           rng.uniform(0.2, 0.9), look, tex(looks[(k + 5) % len(looks)]), 400.0)
        elif kind == 1:
            parts += cylinder(f"can_{k}", c, r, rng.uniform(0.2, 0.8), look, tex(looks[(k + 3) % len(looks)]),
                              segments=48)
        else:
            parts.append(sphere(f"ball_{k}", np.array([*c, r * 0.9]), r, look, segments=48))
    return Setup(parts, Orbit((0.0, 0.0, 0.3), 3.2, 40.0), views=28, background=np.array([0.7, 0.72, 0.7],
                                                                                          np.float32))


def exposure_wb(rng: np.random.Generator) -> Setup:
    # 1536 texels: the 7 m ground without a repeat (a tiled 512 matched photos from opposite sides)
    cobbles = tex(tiles(1536, 1536, rng, 32, [(128, 122, 114), (104, 100, 96), (150, 140, 126)], grout=4,
                        spread=0.12))
    rocket = grid_cells(photo("rocket"), 3, 2, (256, 256))
    retina = photo_tex("retina", 512, 256)
    awning = tex(plaster(64, 64, (190, 70, 60), 8.0, rng, beta=0.8))
    parts = [ground("ground", 3.5, cobbles, 200.0),
             *block("crate_a", rect(0.7, 0.5, 0.4, (-0.6, 0.3)), 0.0, 0.55, tex(rocket[0]), tex(rocket[1]), 350.0),
             *block("crate_b", rect(0.5, 0.5, -0.3, (0.5, 0.6)), 0.0, 0.8, tex(rocket[2]), tex(rocket[3]), 350.0),
             *cylinder("barrel", (0.4, -0.6), 0.3, 0.8, retina, tex(rocket[4])),
             *block("stall", rect(1.2, 0.05, 0.0, (-0.2, -0.2)), 0.0, 1.2, tex(rocket[5]), awning, 350.0)]
    return Setup(parts, Orbit((0.0, 0.0, 0.4), 3.8, 28.0),
                 effects=Effects(exposure_stops=0.7, white_balance=0.12, vignetting=0.4))


def noisy_phone(rng: np.random.Generator) -> Setup:
    sand = tex(mottled(1344, 1344, [(196, 176, 140), (170, 150, 116)], rng, 0.25, beta=0.85))  # 6 m, no repeat
    amphora = [(0.0, 0.0), (0.12, 0.0), (0.22, 0.12), (0.26, 0.3), (0.2, 0.5), (0.1, 0.62), (0.08, 0.72),
               (0.13, 0.78), (0.0, 0.78)]
    cells = grid_cells(photo("cell"), 2, 2, (256, 256))
    camera = grid_cells(photo("camera"), 2, 2, (256, 256))
    parts = [ground("ground", 3.0, sand, 220.0),
             lathe("amphora", (-0.4, 0.3, 0.0), amphora, photo_tex("hubble_deep_field", 512, 256, tint=(2.2, 2.0, 1.8))),
             *block("chest", rect(0.8, 0.5, 0.5, (0.5, 0.2)), 0.0, 0.5, tex(to_rgb(camera[0] * [1.0, 0.85, 0.7])),
                    tex(to_rgb(camera[1] * [0.8, 0.9, 1.0])), 350.0),
             *block("plinth", rect(0.5, 0.5, 0.2, (0.0, -0.7)), 0.0, 0.35, tex(to_rgb(cells[0] * [0.7, 1.0, 0.8])),
                    tex(cells[1]), 350.0),
             sphere("globe", np.array([0.0, -0.7, 0.6]), 0.25, photo_tex("coffee", 256, 128, tint=(0.8, 1.0, 1.1)))]
    return Setup(parts, Orbit((0.0, 0.0, 0.35), 3.2, 30.0, arc_deg=180.0, start_deg=-150.0),
                 effects=Effects(noise=4.0, blur_every=5, blur_px=5.0), jpeg_quality=72)


def facade_walk(rng: np.random.Generator) -> Setup:
    d = 80.0
    wall = bricks(1024, 512, rng, (64, 32), 3, (176, 110, 84), 0.15)
    facade = tex(windows(1024, 512, rng, wall, (128, 160), (64, 96)))
    sidewalk = tex(tiles(512, 512, rng, 64, [(170, 168, 160)], spread=0.05))
    concrete = tex(mottled(256, 256, [(186, 184, 178), (150, 148, 144)], rng, 0.2, beta=0.9))
    metal = tex(plaster(64, 64, (60, 62, 66), 6.0, rng, beta=0.8))
    parts = [ground("ground", 12.0, sidewalk, 80.0),
             *block("building", rect(16.0, 4.0, 0.0, (0.0, 2.0)), 0.0, 6.0, facade, concrete, d)]
    for k, x in enumerate(np.arange(-4.8, 4.81, 3.2)):
        parts += block(f"balcony_{k}", rect(2.0, 0.8, 0.0, (x, -0.4)), 3.2, 0.12, concrete, concrete, d)
        parts += block(f"rail_{k}", rect(2.0, 0.04, 0.0, (x, -0.78)), 3.32, 0.9, metal, metal, d)
    parts += block("step", rect(2.4, 0.6, 0.0, (0.0, -0.3)), 0.0, 0.18, concrete, concrete, d)
    return Setup(parts, Walk((-6.0, -6.0, 1.7), (6.0, -6.0, 1.7), (0.0, 1.0, 0.21)), views=20, focal_factor=0.7,
                 background=gradient_sky, effects=Effects(vignetting=0.25))


def street_forward(rng: np.random.Generator) -> Setup:
    # one texture over the whole road (16 x 40 m at 64 texels/m): a tiled 512 repeated the asphalt every
    # 8 m, which a forward walk matches across tiles (COLMAP and recon both put views 8 m off)
    asphalt = mottled(1024, 2560, [(84, 84, 86), (66, 66, 70)], rng, 0.3, beta=0.7).astype(np.float32)
    asphalt[:, 504:520] = (220, 216, 200)  # the centre line (x = 0) along the street
    road = tex(to_rgb(asphalt))
    parts = [tiled_quad("road", [-8.0, -4.0, 0.0], [16.0, 0, 0], [0, 40.0, 0], road, 64.0)]
    y = -4.0
    k = 0
    while y < 34.0:
        for side in (-1, 1):
            width = rng.uniform(4.0, 7.0)
            height = rng.uniform(5.0, 12.0)
            colour = rng.uniform(120, 220, 3)
            wall = plaster(512, 512, colour, 10.0, rng, beta=0.9)
            facade = tex(windows(512, 512, rng, wall, (128, 128), (64, 80)))
            x0 = side * rng.uniform(4.0, 4.6)
            fp = np.array([[x0, y], [x0 + side * 4.0, y], [x0 + side * 4.0, y + width], [x0, y + width]])
            parts += block(f"house_{k}", fp, 0.0, height, facade, facade, 40.0)
            k += 1
        y += 7.2
    parts += block("end_house", rect(16.0, 3.0, 0.0, (0.0, 36.0)), 0.0, 14.0,
                   tex(windows(512, 512, rng, plaster(512, 512, (200, 190, 170), 10.0, rng), (128, 128), (64, 80))),
                   road, 40.0)
    return Setup(parts, Walk((0.3, 0.0, 1.6), (0.3, 12.0, 1.6), (0.0, 1.0, 0.05), sway=0.06), focal_factor=0.6,
                 background=gradient_sky, effects=Effects(exposure_stops=0.3, noise=1.5))


def aerial_grid(rng: np.random.Generator) -> Setup:
    fields = tex(patchwork(1536, 1536, rng))
    roof = tex(tiles(256, 256, rng, 32, [(150, 70, 56), (110, 104, 100)], grout=2))
    wall = tex(plaster(256, 256, (214, 206, 190), 8.0, rng, beta=0.9))
    crown = tex(mottled(128, 128, [(50, 96, 40), (70, 120, 50)], rng, 0.4, beta=0.7))

    def hills(x, y):
        return 1.6 * np.sin(x / 17.0) * np.cos(y / 23.0) + 0.8 * np.sin((x + 2 * y) / 11.0)

    parts = [heightfield("terrain", (-55.0, 55.0), (-50.0, 50.0), (110, 100), hills, fields, 14.0)]
    for k in range(9):
        cx, cy = rng.uniform(-32, 32), rng.uniform(-26, 26)
        size = (rng.uniform(6, 11), rng.uniform(5, 8), rng.uniform(3, 7))
        z0 = float(hills(np.array(cx), np.array(cy))) - 0.5
        parts += gable_house(f"house_{k}", (cx, cy, z0), size, rng.uniform(0, np.pi), wall, roof, 14.0,
                             rng.uniform(1.5, 3.0))
    for k in range(12):
        cx, cy = rng.uniform(-40, 40), rng.uniform(-35, 35)
        z = float(hills(np.array(cx), np.array(cy)))
        r = rng.uniform(1.5, 3.0)
        parts.append(sphere(f"tree_{k}", np.array([cx, cy, z + r * 0.9]), r, crown, segments=24))
    return Setup(parts, Grid((0.0, 0.0, 0.0), 35.0, lines=4), views=24)


def transient_car(rng: np.random.Generator) -> Setup:
    d = 120.0
    stone = tex(mottled(256, 256, [(172, 166, 154), (140, 136, 128)], rng, 0.3, beta=0.85))
    wall = tex(windows(512, 512, rng, plaster(512, 512, (196, 184, 150), 9.0, rng), (128, 170), (56, 100)))
    paving = tex(tiles(512, 512, rng, 64, [(120, 118, 126), (136, 130, 122)], spread=0.06))
    parts = [ground("ground", 20.0, paving, 80.0),
             *block("building", rect(10.0, 4.0, 0.0, (0.0, 3.0)), 0.0, 5.0, wall, stone, d),
             *sideways("steps", staircase(5, 0.16, 0.3), [0.0, -0.5, 0.0], np.pi / 2, 3.0, stone, stone, d)]
    paint = tex(plaster(128, 128, (170, 30, 36), 6.0, rng, beta=0.8))
    glass = tex(plaster(64, 64, (40, 46, 56), 4.0, rng, beta=0.8))
    tyre = tex(plaster(64, 64, (30, 30, 32), 5.0, rng, beta=0.8))
    car_x, car_y = 0.3, -1.6
    car = [*block("car_body", rect(4.0, 1.7, 0.0, (car_x, car_y)), 0.3, 0.7, paint, paint, d),
           *block("car_cabin", rect(2.2, 1.5, 0.0, (car_x - 0.2, car_y)), 1.0, 0.5, glass, paint, d)]
    for k, (dx, dy) in enumerate(((-1.3, -0.8), (1.3, -0.8), (-1.3, 0.8), (1.3, 0.8))):
        car += sideways(f"car_wheel_{k}", octagon(0.32, (0.0, 0.32)), (car_x + dx, car_y + dy, 0.0), 0.0, 0.22,
                        tyre, tyre, d)
    return Setup(parts, Orbit((0.0, 0.5, 1.0), 9.0, 20.0, arc_deg=150.0, start_deg=-165.0),
                 background=gradient_sky, transient=tuple(car), transient_span=(0.35, 0.7))


def masked_object(rng: np.random.Generator) -> Setup:
    d = 700.0
    wood = tex(planks(512, 512, rng, (160, 112, 70), 64))
    floor = tex(tiles(512, 512, rng, 128, [(200, 196, 186), (70, 70, 74)], spread=0.03))
    room = tex(plaster(256, 256, (222, 214, 200), 6.0, rng, beta=1.0))
    poster = photo_tex("chelsea", 512, 352, wrap=False)
    table = [*block("tabletop", rect(1.4, 0.9), 0.72, 0.04, wood, wood, d)]
    for k, (x, y) in enumerate(((-0.62, -0.38), (0.62, -0.38), (-0.62, 0.38), (0.62, 0.38))):
        table += block(f"leg_{k}", rect(0.05, 0.05, 0.0, (x, y)), 0.0, 0.72, wood, wood, d)
    figurine = [(0.0, 0.76), (0.09, 0.76), (0.1, 0.8), (0.06, 0.86), (0.08, 0.95), (0.05, 1.02), (0.07, 1.08),
                (0.0, 1.12)]
    clutter = [*block("book", rect(0.3, 0.22, 0.3, (-0.4, 0.15)), 0.76, 0.05, photo_tex("page", 256, 128),
                      photo_tex("text", 256, 128), d),
               *cylinder("mug", (0.35, 0.2, 0.76), 0.05, 0.1, photo_tex("colorwheel", 128, 64),
                         tex(plaster(64, 64, (240, 240, 236), 4.0, rng)), segments=48),
               sphere("orange", np.array([0.3, -0.22, 0.8]), 0.04, tex(plaster(64, 32, (230, 130, 40), 12.0, rng)),
                      segments=32),
               *block("box", rect(0.16, 0.12, -0.4, (-0.35, -0.25)), 0.76, 0.12, photo_tex("clock", 128, 128),
                      photo_tex("coins", 128, 128), d)]
    object_parts = [lathe("object_figurine", (0.0, 0.0, 0.0), figurine, photo_tex("immunohistochemistry", 256, 256))]
    walls = [tiled_quad("wall_n", [-3.0, 3.0, 0.0], [6.0, 0, 0], [0, 0, 2.6], room, 150.0),
             tiled_quad("wall_s", [3.0, -3.0, 0.0], [-6.0, 0, 0], [0, 0, 2.6], room, 150.0),
             tiled_quad("wall_e", [3.0, 3.0, 0.0], [0, -6.0, 0], [0, 0, 2.6], room, 150.0),
             tiled_quad("wall_w", [-3.0, -3.0, 0.0], [0, 6.0, 0], [0, 0, 2.6], room, 150.0),
             tiled_quad("ceiling", [-3.0, -3.0, 2.6], [0, 6.0, 0], [6.0, 0, 0], room, 150.0),
             tiled_quad("poster", [-0.8, 2.98, 0.9], [1.6, 0, 0], [0, 0, 1.1], poster, 320.0)]
    parts = [ground("floor", 3.0, floor, 120.0), *walls, *table, *clutter, *object_parts]
    return Setup(parts, Orbit((0.0, 0.0, 0.85), 1.1, 38.0), masked=frozenset(p.name for p in object_parts))


def walkaround(rng: np.random.Generator) -> Setup:
    """A phone walk around a three-storey building, 6 m from its walls: each facade its own wall and
    windows, a flat roof, paving, a tree and a bin off each corner, a bench; 29 photos at eye height,
    GPS tags 3 m off. Along a facade neighbours overlap well; round a corner they are 25-30 degrees
    apart and share only a few dozen matches, and a photo past the corner sees almost nothing two
    photos back: COLMAP's incremental mapper splits the walk into one model per facade (9 + 8 + 6 +
    6 photos at 512x384), the global mapper registers all 29 (AUC@5 91)."""
    d = 110.0
    sx, sy, height = 14.0, 9.0, 8.0
    # 2048 x 1024 texels at ``d``: 18.6 x 9.3 m, so no texture repeats across a facade or the ground
    walls = [bricks(2048, 1024, rng, (64, 32), 3, (176, 110, 84), 0.15),
             plaster(2048, 1024, (206, 196, 170), 9.0, rng),
             bricks(2048, 1024, rng, (32, 16), 2, (150, 126, 104), 0.12),
             plaster(2048, 1024, (182, 196, 204), 9.0, rng)]
    facades = [tex(lived_in_windows(wall, cell, pane, rng))
               for wall, cell, pane in zip(walls, [(128, 160), (160, 176), (128, 160), (144, 192)],
                                           [(64, 96), (96, 104), (56, 88), (80, 120)])]
    paving = tex(tiles(2048, 2048, rng, 64, [(150, 146, 138), (128, 124, 120), (164, 156, 140)], spread=0.08))
    roof = tex(mottled(256, 256, [(96, 92, 90), (70, 68, 66)], rng, 0.3, beta=0.9))
    wood = tex(planks(256, 256, rng, (140, 100, 66), 48))
    corners = rect(sx, sy)
    parts = [ground("ground", 23.0, paving, 43.0)]
    for k in range(4):  # one wall per side, counter-clockwise from the south, each with its own facade
        a, b = corners[k], corners[(k + 1) % 4]
        parts.append(tiled_quad(f"facade_{k}", [*a, 0.0], [*(b - a), 0.0], [0.0, 0.0, height], facades[k], d))
    parts.append(tiled_quad("roof", [-sx / 2, -sy / 2, height], [0.0, sy, 0.0], [sx, 0.0, 0.0], roof, 40.0))
    for k, (cx, cy) in enumerate(corners):  # a tree off each corner, a bin by it, each its own texture
        x, y = cx + np.sign(cx) * 2.2, cy + np.sign(cy) * 2.2
        bark = tex(planks(128, 128, rng, (96, 74, 56), 16))
        leaves = tex(mottled(256, 256, [(58, 96, 44), (96, 128, 60)], rng, 0.45, beta=0.6))
        sticker = photo_tex(("coffee", "rocket", "chelsea", "astronaut")[k], 256, 128, tint=(0.6, 0.8, 0.7))
        parts += cylinder(f"trunk_{k}", (x, y), 0.18, 2.6, bark, bark, segments=16)
        parts.append(sphere(f"crown_{k}", np.array([x, y, 3.6]), 1.3, leaves, segments=32))
        parts += cylinder(f"bin_{k}", (cx + np.sign(cx) * 0.9, cy + np.sign(cy) * 1.6), 0.35, 1.0, sticker, sticker,
                          segments=24)
    parts += block("bench", rect(2.0, 0.5, 0.0, (0.0, -sy / 2 - 1.5)), 0.0, 0.45, wood, wood, d)
    return Setup(parts, Around((0.0, 0.0), (sx, sy), 6.0, aim=3.5, facing=0.3), views=29, holdout=3,
                 focal_factor=0.75, background=gradient_sky, effects=Effects(exposure_stops=0.2, noise=1.5, vignetting=0.2),
                 jpeg_quality=90, gps_sigma=3.0)


def wide_lens(rng: np.random.Generator) -> Setup:
    """A patio seen through a wide-angle lens with barrel distortion, as action cameras and cheap wide
    lenses give: k1 = -0.08 at a focal length of 0.65 x the width, so a corner pixel is imaged about
    23 px nearer the centre at 640x480 and the patio's straight edges bow. The lens is COLMAP's
    SIMPLE_RADIAL family (k1 alone), which recon fits; the photos reach the texture and dense stages
    only through their undistortion."""
    d = 220.0
    # 1536 texels: the 7 m patio without a repeat
    flags = tex(tiles(1536, 1536, rng, 96, [(178, 160, 136), (150, 138, 122), (196, 184, 160)], grout=5,
                      spread=0.1))
    wall = tex(bricks(512, 256, rng, (32, 16), 2, (120, 128, 140), 0.18))
    coping = tex(mottled(256, 256, [(200, 196, 188), (160, 156, 150)], rng, 0.25, beta=0.9))
    terracotta = tex(plaster(256, 128, (190, 104, 70), 9.0, rng, beta=0.9))
    soil = photo_tex("grass", 256, 256, tint=(0.8, 1.0, 0.8))
    stone = photo_tex("gravel", 256, 256, tint=(1.05, 1.0, 0.92))
    slats = tex(planks(256, 256, rng, (120, 90, 70), 40))
    mural = photo_tex("cat", 384, 256, wrap=False)
    parts = [ground("ground", 3.5, flags, d),
             *block("wall_long", rect(3.0, 0.25, 0.0, (0.0, 1.4)), 0.0, 0.9, wall, coping, d),
             *block("wall_short", rect(0.25, 1.6, 0.0, (-1.375, 0.475)), 0.0, 0.9, wall, coping, d),
             tiled_quad("mural", [-0.7, 1.27, 0.15], [1.2, 0, 0], [0, 0, 0.7], mural, 320.0),
             *cylinder("planter_a", (0.9, -0.6), 0.3, 0.5, terracotta, soil, segments=48),
             *cylinder("planter_b", (1.2, 0.7), 0.22, 0.4, terracotta, soil, segments=48),
             *cylinder("sundial", (-0.3, -0.2), 0.18, 0.75, stone, coping, segments=48),
             *sideways("gnomon", np.array([[0.0, 0.75], [0.22, 0.75], [0.0, 0.93]]), (-0.35, -0.2, 0.0), 0.0,
                       0.02, coping, coping, d),
             *block("bench", rect(1.2, 0.4, 0.5, (-0.4, -1.3)), 0.0, 0.42, slats, slats, d)]
    return Setup(parts, Orbit((0.0, 0.0, 0.4), 3.6, 32.0), focal_factor=0.65, background=gradient_sky,
                 radial=(-0.08, 0.0))


def glossy(rng: np.random.Generator) -> Setup:
    """Glazed and lacquered things on a table: a white highlight moves over each from photo to photo, so
    a surface point's colour is not the same in every view (what a glaze, a car's paint or a window does)
    and no texture can show every held-out view's highlights."""
    d = 500.0
    floor = tex(planks(1536, 1536, rng, (150, 120, 92), 96))  # 3 m at 500 texels/m: no repeat
    tabletop = tex(mottled(512, 512, [(92, 70, 52), (70, 54, 42)], rng, 0.3, beta=0.9))
    vase = [(0.0, 0.74), (0.1, 0.74), (0.14, 0.8), (0.15, 0.9), (0.1, 1.02), (0.06, 1.08), (0.075, 1.14),
            (0.0, 1.14)]
    bowl = [(0.0, 0.74), (0.07, 0.74), (0.16, 0.8), (0.2, 0.86), (0.18, 0.87), (0.0, 0.82)]
    lacquer = grid_cells(photo("motorcycle"), 2, 1, (256, 256))
    parts = [ground("floor", 1.5, floor, d),
             *(dataclasses.replace(p, gloss=0.3) for p in block("table", rect(1.2, 0.8), 0.0, 0.74, tabletop, tabletop,
                                                                   d)),
             dataclasses.replace(lathe("vase", (-0.25, 0.1, 0.0), vase, photo_tex("coffee", 512, 256,
                                                                                  tint=(0.7, 0.8, 1.1))), gloss=0.7),
             dataclasses.replace(lathe("bowl", (0.3, -0.15, 0.0), bowl, photo_tex("clock", 512, 128,
                                                                                 tint=(1.1, 0.9, 0.7))), gloss=0.5),
             *(dataclasses.replace(p, gloss=0.6) for p in block("box", rect(0.22, 0.16, 0.4, (0.25, 0.22)), 0.74,
                                                                 0.12, tex(lacquer[0]), tex(lacquer[1]), d)),
             dataclasses.replace(sphere("ball", np.array([-0.2, -0.22, 0.8]), 0.06, photo_tex("logo", 256, 128)),
                                 gloss=0.8)]
    return Setup(parts, Orbit((0.0, 0.0, 0.8), 1.6, 35.0), background=np.array([0.35, 0.36, 0.4], np.float32))
