"""Models in metres on the Earth: each model's camera centres aligned to its photos' GPS positions,
the model then transformed into one local East-North-Up frame (metres, origin at the photos'
median GPS position), which every later stage reads.

The content of ``georeference.json`` is built here; its keys are documented in :func:`georeference`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from recon.geometry.georef import CHI3_99, Alignment, GeorefError, align_to_gps
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu

log = logging.getLogger(__name__)

#: GPS accuracy (metres) of a photo that states none: a phone or camera GPS in the open
DEFAULT_GPS_SIGMA = 5.0
CRS = "local ENU: x east, y north, z up, metres, in the plane tangent to the WGS84 ellipsoid at the origin"
ALTITUDE_NOTE = ("EXIF GPSAltitude (above mean sea level) is used as the WGS84 ellipsoid height: heights in "
                 "the frame are right relative to each other, the origin's altitude is off by the geoid height")


def gps_positions(images: list[dict]) -> dict[str, dict]:
    """Image name -> its ``gps`` record from an ``images.json`` list, for photos with a full position
    (latitude, longitude and altitude)."""
    return {img["name"]: img["gps"] for img in images
            if img.get("gps") and img["gps"].get("alt") is not None}


def gps_sigma(tag: dict, override: float) -> float:
    """A photo's GPS accuracy in metres: ``override`` when > 0, else its GPSHPositioningError, else its
    GPSDOP read as metres (phones write their accuracy there), else DEFAULT_GPS_SIGMA."""
    if override > 0:
        return override
    return float(tag.get("horizontal_error") or tag.get("dop") or DEFAULT_GPS_SIGMA)


def median_origin(tags: list[dict]) -> tuple[float, float, float]:
    """(lat, lon, alt): the median GPS position (per ENU axis around the first tag, so a few wild
    positions do not move it and longitudes need no wrapping)."""
    lla = np.array([[t["lat"], t["lon"], t["alt"]] for t in tags], dtype=float)
    first = tuple(lla[0])
    return tuple(float(v) for v in wgs84_from_enu(np.median(enu_from_wgs84(lla, first), axis=0), first)[0])


@dataclass(frozen=True, eq=False)
class _Fit:
    names: list[str]  # registered photos with GPS, sorted
    gps_enu: np.ndarray  # (N, 3) their GPS positions in the frame
    alignment: Alignment


def georeference(models: list, gps: dict[str, dict], *, sigma: float = 0.0, seed: int = 0) -> dict:
    """Transform ``models`` (pycolmap Reconstructions, largest first) in place into the local ENU frame,
    each that its photos' GPS positions ``gps`` (name -> gps record) fix; returns georeference.json.

    The first model is aligned when at least 3 of its photos, and more than half, have GPS; the others
    only then, into the same frame. ``sigma`` > 0 replaces every photo's GPS accuracy (metres).
    Keys: ``georeferenced`` and ``reason`` (why not), ``crs``, ``origin`` (lat, lon, alt),
    ``altitude``, ``model_to_enu`` (scale, rotation, translation), ``residuals_m`` (median, p90 of
    the inliers), ``scale_relative_std`` and ``position_std_m`` (bootstrap), ``outliers``,
    ``photos`` (per photo with GPS: its position, the camera centre in the frame, the residual),
    ``without_gps``, ``other_models``.
    """
    if not models:
        return {"georeferenced": False, "reason": "no model was built"}
    main = models[0]
    names = [main.image(i).name for i in main.reg_image_ids()]
    tagged = [n for n in names if n in gps]
    if len(tagged) < 3 or 2 * len(tagged) <= len(names):
        return {"georeferenced": False,
                "reason": f"{len(tagged)} of the {len(names)} registered photos have a GPS position with "
                          "altitude; georeferencing needs at least 3 and more than half"}
    origin = median_origin(list(gps.values()))
    try:
        fit = _align(main, gps, origin, sigma, seed)
    except GeorefError as exc:
        return {"georeferenced": False, "reason": f"GPS cannot place the model: {exc}"}
    _transform(main, fit.alignment)
    result = {
        "georeferenced": True,
        "crs": CRS,
        "origin": dict(zip(("lat", "lon", "alt"), origin)),
        "altitude": ALTITUDE_NOTE,
        **_summary(fit, sigma),
        "photos": [_photo_record(fit, k, gps[name]) for k, name in enumerate(fit.names)],
        "without_gps": sorted(set(names) - set(tagged)),
        "other_models": [],
    }
    for k, model in enumerate(models[1:], start=1):
        result["other_models"].append({"model": k, **_georeference_other(model, gps, origin, sigma, seed)})
    return result


def _align(model, gps: dict[str, dict], origin, sigma: float, seed: int) -> _Fit:
    images = [model.image(i) for i in model.reg_image_ids()]
    images = sorted((img for img in images if img.name in gps), key=lambda img: img.name)
    if len(images) < 3:
        raise GeorefError(f"{len(images)} registered photo(s) have GPS: at least 3 are needed")
    names = [img.name for img in images]
    centres = np.array([img.projection_center() for img in images])
    enu = enu_from_wgs84(np.array([[gps[n]["lat"], gps[n]["lon"], gps[n]["alt"]] for n in names]), origin)
    sigmas = np.array([gps_sigma(gps[n], sigma) for n in names])
    alignment = align_to_gps(centres, enu, sigmas, seed=seed)
    if 2 * alignment.inliers.sum() <= len(names):
        raise GeorefError(f"only {int(alignment.inliers.sum())} of {len(names)} photos agree with the model "
                          f"within {CHI3_99:.1f} x their GPS accuracy; if the GPS is worse than its tags say, "
                          "set sfm.gps_sigma (metres)")
    return _Fit(names, enu, alignment)


def _transform(model, alignment: Alignment) -> None:
    import pycolmap

    sim = alignment.similarity
    model.transform(pycolmap.Sim3d(sim.s, pycolmap.Rotation3d(sim.R), sim.t))


def _summary(fit: _Fit, sigma: float) -> dict:
    alignment = fit.alignment
    sim = alignment.similarity
    return {
        "model_to_enu": {"scale": sim.s, "rotation": sim.R.tolist(), "translation": sim.t.tolist(),
                         "maps": "x_enu = scale * rotation @ x_model + translation (x_model: the mapper's frame)"},
        "residuals_m": {"median": alignment.median, "p90": alignment.p90,
                        "what": "distance between each inlier photo's camera centre and its GPS position"},
        # None with fewer than 4 inliers: a bootstrap over 3 photos says nothing
        "scale_relative_std": None if np.isnan(alignment.scale_std) else alignment.scale_std,
        "position_std_m": None if np.isnan(alignment.position_std) else alignment.position_std,
        "inlier_threshold": f"{CHI3_99} x each photo's GPS sigma" + (f" ({sigma} m, sfm.gps_sigma)" if sigma > 0 else ""),
        "inliers": int(alignment.inliers.sum()),
        "outliers": [name for name, ok in zip(fit.names, alignment.inliers) if not ok],
    }


def _photo_record(fit: _Fit, k: int, tag: dict) -> dict:
    alignment = fit.alignment
    return {"name": fit.names[k], "lat": tag["lat"], "lon": tag["lon"], "alt": tag["alt"],
            "sigma_m": float(alignment.thresholds[k] / CHI3_99), "gps_enu": fit.gps_enu[k].tolist(),
            "camera_enu": alignment.aligned[k].tolist(), "residual_m": float(alignment.residuals[k]),
            "inlier": bool(alignment.inliers[k])}


def _georeference_other(model, gps, origin, sigma: float, seed: int) -> dict:
    try:
        fit = _align(model, gps, origin, sigma, seed)
    except GeorefError as exc:
        return {"georeferenced": False, "reason": str(exc)}
    _transform(model, fit.alignment)
    return {"georeferenced": True, **_summary(fit, sigma)}
