"""The scene zoo: named synthetic scenes, each made to stress what breaks dense reconstruction and
texturing in practice, all with exact ground truth (cameras, depth, normals, surface mesh) and
held-out views for scoring textures.

    render_zoo("courtyard", "out/courtyard")        # the layout of recon.synth.dataset
    for name, summary in zoo_list(): ...

Each scene has its own geometry, textures (scikit-image photos and procedural ones, recon.synth.
procedural), camera layout (recon.synth.layouts), background and capture effects
(recon.synth.effects); the builders are in recon.synth.zoo_scenes.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import hashlib
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from recon.synth import zoo_scenes as zs
from recon.synth.dataset import FORMATS, Capture, SceneInfo, write_scene
from recon.synth.geotags import noisy_geotags
from recon.synth.layouts import layout_cameras
from recon.synth.scene import assemble

#: name -> (what it tests, builder); the order of ``recon synth --list``
SCENES: dict[str, tuple[str, Callable[[np.random.Generator], zs.Setup]]] = {
    "classic": ("the demo's scene: photo-textured solids on gravel and grass, full orbit (the tuned-on reference)",
                zs.classic),
    "courtyard": ("concave shapes and sharp corners: U- and L-shaped walls, a notched block, stairs; half orbit, "
                  "sky", zs.courtyard),
    "plain_boxes": ("weak texture: boxes, a drum and a ball painted in near-uniform colours on plain concrete; "
                    "full orbit", zs.plain_boxes),
    "turntable_black": ("black background: a vase (concave profile) on a marble pedestal floating in black; "
                        "full orbit", zs.turntable_black),
    "far_field": ("large depth range: a shed and barrels on an 80 m meadow seen at grazing angles to the "
                  "horizon, sky; half orbit", zs.far_field),
    "fence_poles": ("thin structures: fence posts and rails, poles, bench slats before a wall and the sky; "
                    "full orbit", zs.fence_poles),
    "clutter": ("clutter and heavy occlusion: 26 packed crates, cans and balls; full orbit from above",
                zs.clutter),
    "exposure_wb": ("per-view exposure (+-0.7 stops) and white balance (+-12 %) changes, vignetting; full orbit",
                    zs.exposure_wb),
    "noisy_phone": ("sensor noise, JPEG quality 72, motion blur on every 5th view; half orbit", zs.noisy_phone),
    "facade_walk": ("a walk past a facade (balconies, windows, sky above), vignetting", zs.facade_walk),
    "street_forward": ("forward walk down a street: wide angle, epipole in view, sky above, mild auto-exposure "
                       "and noise", zs.street_forward),
    "aerial_grid": ("aerial nadir survey, 4 flight lines, 70 % forward / 60 % side overlap: hills, houses, trees",
                    zs.aerial_grid),
    "transient_car": ("a car parked before a building's steps in a third of the photos only (ground truth and "
                      "held-out views without it); half orbit", zs.transient_car),
    "masked_object": ("object capture on a cluttered table in a room, with masks of the object "
                      "(masks/<image name>.png); close orbit", zs.masked_object),
    "walkaround": ("phone photos walking around a building: facades seen square-on, about 30 degrees between "
                   "neighbours round the corners, sky, GPS tags with a few metres of noise", zs.walkaround),
    "wide_lens": ("a wide-angle lens with barrel distortion (k1 -0.08, corners imaged about 23 px inward at "
                  "640x480): a patio with a wall, planters, a sundial; full orbit", zs.wide_lens),
    "glossy": ("view-dependent colour: glazed and lacquered things on a table, a highlight moving over each "
               "from photo to photo; full orbit", zs.glossy),
}


class UnknownScene(ValueError):
    pass


def zoo_list() -> list[tuple[str, str]]:
    """(name, what it tests) of every zoo scene."""
    return [(name, summary) for name, (summary, _) in SCENES.items()]


@functools.cache
def zoo_setup(name: str) -> zs.Setup:
    """The scene ``name``'s parts, layout and capture (cached; treat as read-only)."""
    if name not in SCENES:
        close = difflib.get_close_matches(name, SCENES, n=1)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise UnknownScene(f"unknown zoo scene {name!r}{hint} (`recon synth --list` lists them)")
    return SCENES[name][1](np.random.default_rng(zlib.crc32(name.encode())))


def zoo_digest(name: str) -> str:
    """A fingerprint of what scene ``name`` is made of (geometry, textures, layout, capture): it changes
    whenever the scene's definition does, so a rendering made before can be told stale."""
    setup = zoo_setup(name)
    digest = hashlib.sha256()
    for part in (*setup.parts, *setup.transient):
        for array in (part.vertices, part.faces, part.uv, part.texture.levels[0]):
            digest.update(np.ascontiguousarray(array).tobytes())
        if part.gloss:  # a glossy scene's rendering holds diffuse hold-out views: one made before them is stale
            digest.update(repr((part.gloss, "holdout/diffuse")).encode())
    background = setup.background
    lens = (setup.radial,) if any(setup.radial) else ()  # none for a pinhole: earlier renderings stay valid
    digest.update(repr((setup.layout, setup.views, setup.holdout, setup.focal_factor, setup.effects,
                        setup.jpeg_quality, setup.transient_span, sorted(setup.masked), setup.gps_sigma, *lens,
                        getattr(background, "__name__", None) or np.asarray(background).tolist())).encode())
    return digest.hexdigest()[:16]


def render_zoo(name: str, out_dir: str | Path, views: int | None = None, width: int = 640, height: int = 480,
               seed: int = 0, holdout: int | None = None, image_format: str = "jpg") -> SceneInfo:
    """Render zoo scene ``name`` into ``out_dir`` (the layout of recon.synth.dataset). ``views`` and
    ``holdout`` default to the scene's own; ``seed`` moves the cameras' jitter and the photo effects."""
    if image_format not in FORMATS:
        raise ValueError(f"image_format must be one of {FORMATS}, got {image_format!r}")
    setup = zoo_setup(name)
    views = setup.views if views is None else views
    holdout = setup.holdout if holdout is None else holdout
    regular, held = layout_cameras(setup.layout, views, holdout, width, height, setup.focal_factor, seed,
                                   image_format)
    if any(setup.radial):
        regular, held = ({name: dataclasses.replace(cam, radial=setup.radial) for name, cam in cams.items()}
                         for cams in (regular, held))
    start, end = setup.transient_span
    effects = setup.effects
    capture = Capture(background=setup.background,
                      develop=(lambda rgb, index: effects.apply(rgb, index, seed)) if effects else None,
                      jpeg_quality=setup.jpeg_quality, transient=setup.transient,
                      transient_views=frozenset(i for i in range(views) if start <= i / views < end),
                      masked=setup.masked,
                      geotags=noisy_geotags({n: c.center for n, c in regular.items()}, setup.gps_sigma, seed)
                      if setup.gps_sigma else {})
    return write_scene(out_dir, assemble(setup.parts), regular, held, seed=seed, path=type(setup.layout).__name__.lower(),
                       image_format=image_format, name=name, capture=capture)
