"""Which depth maps of an earlier run a new mvs run may reuse (photos added to a workspace).

A view's final (geometric) depth and normal maps are determined by its photometric maps and those
of its source views, each of which is determined by the view's photo, its sources' photos, the
cameras of all of them, its depth range, its mask and the PatchMatch options. The exact part of
that (photos' and masks' content, names, options, seed) is hashed into item keys
(:func:`recon.items.item_key`); the cameras and depth ranges are not, because every bundle
adjustment moves them a little (continuing a model with new photos moves every camera, and
undistortion then resamples every photo), and a hash would never match. They go into the item's
record instead, and :func:`reusable` compares them within a tolerance:

- cameras, relative to the view's own: a depth map lives in its view's camera frame and follows it,
  so what decides it is how its sources sit relative to it and every camera's intrinsics, not
  where the model put the group. A grid of the view's pixels at the near and far ends of its depth
  range is projected into each camera (the view's own included) with the stored and the current
  cameras; every projection must agree within ``max_shift`` working-resolution pixels, in the
  undistorted image and in the photo behind it, through the photo's own (distorted) camera model
  (the undistorted image the map was matched on must show the same content). Consistency filtering
  and fusion ask 1 px of agreement between views; the default tolerance is half of that.
- depth range: the view's stored search range must cover its current sparse points' 1-99
  percentile depths (the current range without its margin): no depth the surface now has went
  unsearched.

A final map's item is keyed by the view's photometric item, the options only the final part reads
(:data:`FINAL_ONLY`) and its sources' masks, not by its sources' photometric maps: those only check
its depths (the geometric pass), and an earlier map of the same source photo, from the same
cameras, checks them as well as a recomputed one. Keyed by them, a source whose own sources or range
changed made every view using it recompute: on the zoo scene below, one view's grown range cost 9
maps, and 8 views choosing new sources cost all 20.

Measured on the zoo's classic scene (320x240), 20 views then 4 added: after sfm continued the
model, each view's sources had moved relative to it by 0.07 to 0.30 px (0.21 median of each view's
worst source), its intrinsics by 0.04 px: the bundle adjustment's own noise, which a recomputed
map would carry too. The shift in pixels grows with the working resolution, so at larger sizes
fewer maps pass.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from recon.items import item_key
from recon.mvs.options import MVSOptions
from recon.mvs.views import Problem, ViewCamera


@dataclass(frozen=True)
class ViewInput:
    """What one view brings to the maps it takes part in: the content digests of its photo and mask,
    and its camera (:func:`camera_record`)."""

    image: str
    mask: str | None
    camera: dict


@dataclass(frozen=True)
class MapItem:
    """The item key of a view's maps and its record's ``meta`` (the cameras and depth ranges)."""

    key: str
    meta: dict


def camera_record(view: ViewCamera, photo=None) -> dict:
    """A view's undistorted pinhole camera and, when known, the camera of the photo it was undistorted
    from (a pycolmap Camera: its model and parameters), as plain data for an item's record."""
    record = {"K": view.K.tolist(), "R": view.R.tolist(), "t": view.t.tolist(), "size": [view.width, view.height]}
    if photo is not None:
        record["photo"] = {"model": photo.model.name, "params": list(map(float, photo.params)),
                           "size": [int(photo.width), int(photo.height)]}
    return record


#: the mvs stage's version since which photometric maps are made as now: a new one (the stage's version
#: then) makes every view's photometric maps again. A new final version makes only its final maps again
#: (the geometric pass, the filter, the test at infinity, the background clearing and the fill), from the
#: stored photometric maps. The mvs stage's own version changes with either.
PHOTOMETRIC_VERSION = 16
FINAL_VERSION = 4

#: the options only the geometric pass, the filter, the test at infinity, the silhouette check, the
#: background clearing and the fill read: they key a view's final maps, not its photometric ones, so
#: changing one runs the final part again from the stored photometric maps
FINAL_ONLY = ("geometric", "geometric_iterations", "geometric_weight", "geometric_max_error", "filter_max_cost",
              "filter_min_consistent", "filter_unconfirmed_cost", "filter_max_reprojection", "filter_max_depth_error",
              "filter_grazing_allowance", "planar_fill", "clear_background", "drop_fattened", "drop_at_infinity")


def _options(options: MVSOptions, final: bool) -> dict:
    """The options a view's photometric maps depend on, or (``final``) those only its final maps do (the
    thread count only splits the work)."""
    return {f.name: getattr(options, f.name) for f in fields(MVSOptions)
            if f.name != "num_threads" and (f.name in FINAL_ONLY) == final}


def photometric_items(problems: list[Problem], inputs: dict[str, ViewInput], options: MVSOptions) -> dict[str, MapItem]:
    """Per reference view, the item of its photometric depth map; its meta is one part (:func:`part`)."""
    settings = _options(options, final=False)
    items = {}
    for p in problems:
        views = (p.ref, *p.sources)
        key = item_key({"item": "photometric_depth", "version": PHOTOMETRIC_VERSION, "options": settings, "ref": p.ref,
                        "images": [[n, inputs[n].image] for n in views], "mask": inputs[p.ref].mask})
        items[p.ref] = MapItem(key, {"parts": [{"ref": p.ref, "cameras": {n: inputs[n].camera for n in views},
                                                "range": [p.depth_min, p.depth_max]}]})
    return items


def geometric_items(problems: list[Problem], photometric: dict[str, MapItem], inputs: dict[str, ViewInput],
                    options: MVSOptions) -> dict[str, MapItem]:
    """Per reference view, the item of its final depth and normal maps (module doc): made from its
    photometric maps, checked against those of its sources that have any
    (:func:`recon.mvs.stereo.geometric_view`), masked sources' depths cleared."""
    items = {}
    for p in problems:
        used = [s for s in p.sources if s in photometric]
        key = item_key({"item": "geometric_maps", "version": FINAL_VERSION, "photometric": photometric[p.ref].key,
                        "options": _options(options, final=True),
                        "checked_against": [[s, inputs[s].mask] for s in used]})
        items[p.ref] = MapItem(key, photometric[p.ref].meta)
    return items


def reusable(stored: dict | None, now: dict, max_shift: float, depth_margin: float, max_image_size: int) -> bool:
    """Whether an item recorded with ``stored`` (its ``meta``) stands for one made now with ``now``:
    per part, the same views, every camera within ``max_shift`` working pixels relative to the
    part's view, its range covered (module doc)."""
    parts = (stored or {}).get("parts")
    if not isinstance(parts, list) or len(parts) != len(now["parts"]):
        return False
    for old, new in zip(parts, now["parts"]):
        if old.get("ref") != new["ref"] or old.get("cameras", {}).keys() != new["cameras"].keys():
            return False
        (near, far), (now_near, now_far) = old["range"], new["range"]
        if near > now_near * (1 + depth_margin) or far < now_far / (1 + depth_margin):
            return False
        ref = new["ref"]
        for name in new["cameras"]:
            shift = camera_shift(old["cameras"][ref], new["cameras"][ref], old["cameras"][name],
                                 new["cameras"][name], (near, far), max_image_size)
            if shift > max_shift:
                return False
    return True


def camera_shift(old_ref: dict, new_ref: dict, old: dict, new: dict, depth_range: tuple[float, float],
                 max_image_size: int) -> float:
    """How far, in the working-resolution pixels of a camera (longest side at most ``max_image_size``),
    a grid of the reference view's pixels at the ends of ``depth_range`` projects from the stored
    cameras (``old_ref``, ``old``) to the current ones, relative to the reference (module doc): in
    the undistorted image, and in the photo behind it. ``old`` may be the reference itself (its
    intrinsics then decide). Infinite where sizes or models differ."""
    if any(a["size"] != b["size"] or ("photo" in a) != ("photo" in b) for a, b in ((old_ref, new_ref), (old, new))):
        return float("inf")
    if "photo" in old and (old["photo"]["model"], old["photo"]["size"]) != (new["photo"]["model"],
                                                                             new["photo"]["size"]):
        return float("inf")
    width, height = old_ref["size"]
    u, v = np.meshgrid(np.linspace(0.5, width - 0.5, 5), np.linspace(0.5, height - 0.5, 5))
    rays = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1) @ np.linalg.inv(np.asarray(old_ref["K"])).T
    points = np.concatenate([rays * depth for depth in depth_range])  # in the reference's frame
    seen = [points @ r.T + t for r, t in (_relative(old_ref, old), _relative(new_ref, new))]
    ahead = [x[:, 2] > 0 for x in seen]
    if np.any(ahead[0] != ahead[1]):
        return float("inf")
    pixels = [x @ np.asarray(cam["K"]).T for x, cam in zip(seen, (old, new))]
    pixels = [p[:, :2] / np.where(ahead[0], p[:, 2:].T, 1.0).T for p in pixels]
    # only what the camera sees: far outside its image a lens model's polynomial means nothing
    inside = ahead[0] & np.all((pixels[0] >= 0) & (pixels[0] <= old["size"]), axis=1)
    if not inside.any():
        return 0.0
    seen, pixels = [x[inside] for x in seen], [p[inside] for p in pixels]
    scale = min(1.0, max_image_size / max(old["size"]))  # pixels -> working pixels
    worst = float(np.linalg.norm(pixels[1] - pixels[0], axis=1).max()) * scale
    if "photo" in old:
        photo = [_photo_camera(cam["photo"]).img_from_cam(x, check_cheirality=False) for x, cam in zip(seen, (old, new))]
        photo_scale = scale * old["size"][0] / old["photo"]["size"][0]  # photo pixels -> working pixels
        worst = max(worst, float(np.linalg.norm(photo[1] - photo[0], axis=1).max()) * photo_scale)
    return worst


def _relative(ref: dict, cam: dict) -> tuple[np.ndarray, np.ndarray]:
    """(R, t) taking points from the reference camera's frame to ``cam``'s (x_c = R x_ref + t)."""
    r_ref, t_ref = np.asarray(ref["R"]), np.asarray(ref["t"])
    r_cam, t_cam = np.asarray(cam["R"]), np.asarray(cam["t"])
    r = r_cam @ r_ref.T
    return r, t_cam - r @ t_ref


def _photo_camera(record: dict):
    import pycolmap

    width, height = record["size"]
    return pycolmap.Camera(model=record["model"], width=width, height=height, params=record["params"])
