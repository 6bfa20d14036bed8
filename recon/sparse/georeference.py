"""Models in metres on the Earth: each model's camera centres aligned to its photos' GPS positions,
the model then transformed into one local East-North-Up frame (metres, origin at the photos'
median GPS position), which every later stage reads. Ground control points move the first model
onto their surveyed positions (jointly with the GPS photos that agree); scale bars scale it
(:func:`place`; README, "Metric scale and ground control").

The content of ``georeference.json`` is built here; its keys are documented in :func:`georeference`
and :func:`place`.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from recon.geometry.gcp import GcpList, to_wgs84
from recon.geometry.georef import CHI3_99, Alignment, GeorefError, align_to_control, align_to_gps
from recon.geometry.gps import enu_from_wgs84, wgs84_from_enu
from recon.geometry.scale import BarScale, fit_scale
from recon.geometry.transforms import Similarity
from recon.geometry.utm import enu_to_utm
from recon.sparse import gps_prior
from recon.sparse.control import ControlError, ScaleBar, triangulate
from recon.sparse.markers import Found

log = logging.getLogger(__name__)

#: GPS accuracy (metres) of a photo that states none: a phone or camera GPS in the open
DEFAULT_GPS_SIGMA = 5.0
CRS = "local ENU: x east, y north, z up, metres, in the plane tangent to the WGS84 ellipsoid at the origin"
GCP_LOCAL_CRS = "the GCP file's local frame (ENU: x east, y north, z up, metres), not tied to the Earth"
#: how far (metres) a GCP triangulated in a model may be from its surveyed position: survey, clicking and
#: model error together; a GCP beyond CHI3_99 of these is left out of the fit
DEFAULT_GCP_SIGMA = 0.1
ALTITUDE_NOTE = ("EXIF GPSAltitude (above mean sea level) is used as the WGS84 ellipsoid height: heights in "
                 "the frame are right relative to each other, the origin's altitude is off by the geoid height")


def gps_positions(images: list[dict]) -> dict[str, dict]:
    """Image name -> its ``gps`` record from an ``images.json`` list, for photos with a full position
    (latitude, longitude and altitude)."""
    return {img["name"]: img["gps"] for img in images
            if img.get("gps") and img["gps"].get("alt") is not None}


def gps_sigma(tag: dict, override: float) -> float:
    """A photo's GPS accuracy in metres: ``override`` when > 0, else its GPSHPositioningError, else the
    larger of an RTK drone's XMP RtkStdLon / RtkStdLat, else its GPSDOP read as metres (phones write
    their accuracy there), else DEFAULT_GPS_SIGMA."""
    if override > 0:
        return override
    rtk = max(tag.get("rtk_std_lon") or 0.0, tag.get("rtk_std_lat") or 0.0)
    return float(tag.get("horizontal_error") or rtk or tag.get("dop") or DEFAULT_GPS_SIGMA)


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


def georeference(models: list, gps: dict[str, dict], *, sigma: float = 0.0, seed: int = 0,
                 prior: str | None = "off", ba_options=None, groups: int = 1) -> dict:
    """Transform ``models`` (pycolmap Reconstructions, largest first) in place into the local ENU frame,
    each that its photos' GPS positions ``gps`` (name -> gps record) fix; returns georeference.json.

    The first model is aligned when at least 3 of its photos, and more than half, have GPS; the others
    only then, into the same frame. ``sigma`` > 0 replaces every photo's GPS accuracy (metres).
    ``prior`` (auto / on / off; None: a continued model, whose photos keep their poses) says whether
    the first model is then bundle-adjusted with its inlier photos' GPS positions as priors
    (:mod:`recon.sparse.gps_prior`), with ``ba_options`` (pycolmap BundleAdjustmentOptions); ``groups``:
    the first model's groups of photos tied by few points (:mod:`recon.sparse.weak_joins`), which
    ``auto`` weighs.
    Keys: ``georeferenced`` and ``reason`` (why not), ``crs``, ``origin`` (lat, lon, alt),
    ``altitude``, ``model_to_enu`` (scale, rotation, translation), ``gps_prior`` (used, why, and
    the reprojection error before and after), ``residuals_m`` (median, p90 of the inliers),
    ``scale_relative_std`` and ``position_std_m`` (bootstrap), ``outliers``, ``photos`` (per photo
    with GPS: its position, the camera centre in the frame, the residual), ``without_gps``,
    ``other_models``.
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
    _transform(main, fit.alignment.similarity)
    placed = fit.alignment.similarity
    adjusted = _gps_prior(main, fit, prior, ba_options, groups)
    if adjusted["used"]:  # the residuals after the adjustment, and the little move they still ask
        fit = _align(main, gps, origin, sigma, seed)
        _transform(main, fit.alignment.similarity)
        placed = _compose(fit.alignment.similarity, placed)
    result = {
        "georeferenced": True,
        "crs": CRS,
        "origin": dict(zip(("lat", "lon", "alt"), origin)),
        "altitude": ALTITUDE_NOTE,
        **_summary(fit, sigma),
        "model_to_enu": _similarity_record(placed),
        "gps_prior": adjusted,
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


def _gps_prior(model, fit: _Fit, mode: str | None, ba_options, groups: int) -> dict:
    """Bundle-adjust ``model`` with its inlier photos' GPS positions as priors when ``mode`` asks for it
    (:func:`recon.sparse.gps_prior.decide`); what was done."""
    if mode is None:
        return {"used": False, "why": "a continued model keeps its photos' poses"}
    inliers = fit.alignment.inliers
    sigmas = fit.alignment.thresholds[inliers] / CHI3_99
    used, why = gps_prior.decide(mode, sigmas, groups)
    record = {"used": used, "why": why}
    if used:
        names = [name for name, ok in zip(fit.names, inliers, strict=True) if ok]
        record.update(gps_prior.adjust(model, names, fit.gps_enu[inliers], sigmas, ba_options))
    return record


def _transform(model, sim: Similarity) -> None:
    import pycolmap

    model.transform(pycolmap.Sim3d(sim.s, pycolmap.Rotation3d(sim.R), sim.t))


def _summary(fit: _Fit, sigma: float) -> dict:
    alignment = fit.alignment
    return {
        "model_to_enu": _similarity_record(alignment.similarity),
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
    _transform(model, fit.alignment.similarity)
    return {"georeferenced": True, **_summary(fit, sigma)}


def place(models: list, gps: dict[str, dict] | None, *, sigma: float = 0.0, seed: int = 0,
          gcps: GcpList | None = None, gcp_sigma: float = DEFAULT_GCP_SIGMA,
          scale_bars: Sequence[ScaleBar] = (), markers: Sequence[Found] = (), prior: str | None = "off",
          ba_options=None, crs: str = "enu", groups: int = 1) -> dict:
    """Put ``models`` (largest first) in metres, in place, from what the user has: the photos' GPS
    (``gps``; None: not used; ``prior``, ``ba_options``, ``groups``: :func:`georeference`), ground control points
    (``gcps``, the first model), scale bars (the first model); returns georeference.json, whose ``scale_source`` says which fixed the scale
    ("GCP", "scale bar", "GPS" or "none").

    GCPs, far more accurate than phone or drone GPS, move the model to them, jointly with the GPS
    photos that agree (weights 1 / sigma^2); scale bars then only check the result. Without GCPs,
    scale bars set the scale: about the GPS photos' centroid when GPS placed the model (the
    position and rotation GPS fixed stay), about the origin otherwise. Raises
    :class:`recon.sparse.control.ControlError` for marked points that cannot be used, its message
    starting with the option at fault (``gcp_file: ...``, ``scale_bars[0].a: ...``).

    Keys beyond :func:`georeference`'s: ``scale_source``; ``gcp`` (per GCP its residual and
    leave-one-out check in metres, outliers, GCPs not used and why); ``scale_bars`` (per bar its
    length and its length in the model); ``model_scale`` (the scale applied to a model that stays
    in the mapper's frame); ``gps`` (why GPS was not used when GCPs placed the model).

    ``markers``: printed targets found in the photos (:func:`recon.sparse.markers.search`; ArUco
    markers, a chessboard), measured in the first model after the scale bars and, like them, setting
    the scale unless GCPs, scale bars or an earlier kind of target fixed it (``scale_source``
    "ArUco markers", "chessboard"); ``markers`` in the result: one record per kind (:func:`_apply_markers`).

    ``crs`` "utm": a model placed on the Earth ends in its UTM zone minus whole kilometres instead of
    local ENU (``utm``: zone, EPSG code, offset, the ENU-to-frame similarity and its largest error);
    the per-photo and per-GCP ``*_enu`` positions stay in the local ENU frame.
    """
    if gps is None:
        result = {"georeferenced": False, "reason": "sfm.georeference is off"}
    elif not gps:
        result = {"georeferenced": False, "reason": "no photo has a GPS position with altitude in its EXIF"}
    else:
        result = georeference(models, gps, sigma=sigma, seed=seed, prior=prior, ba_options=ba_options, groups=groups)
    result["scale_source"] = "GPS" if result["georeferenced"] else "none"
    if models and gcps is not None:
        _apply_gcps(models[0], result, gcps, gcp_sigma)
    if models and scale_bars:
        _apply_scale_bars(models[0], result, scale_bars)
    for found in markers if models else ():
        _apply_markers(models[0], result, found)
    if crs == "utm":
        _to_utm(models, result)
    return result


def _to_utm(models: list, result: dict) -> None:
    """Move the models placed on the Earth from local ENU into their UTM zone minus whole kilometres
    (:mod:`recon.geometry.utm`); the ``utm`` record, or why the frame stays as it is."""
    if not result["georeferenced"] or result.get("origin") is None:
        where = "its GCPs are in a local frame" if result["georeferenced"] else result["reason"]
        result["utm"] = {"used": False, "why": f"the model is not placed on the Earth ({where})"}
        return
    placed = [models[0]] + [models[o["model"]] for o in result.get("other_models", []) if o["georeferenced"]]
    origin = tuple(result["origin"][k] for k in ("lat", "lon", "alt"))
    frame = enu_to_utm(origin, np.concatenate([np.array(list(_centres(m).values())) for m in placed]))
    for model in placed:
        _transform(model, frame.from_enu)
    result["crs"] = (f"EPSG:{frame.epsg} (WGS 84 / UTM zone {frame.zone}): x easting, y northing, z height, "
                     f"metres, minus the offset {list(frame.offset)}")
    result["utm"] = {"used": True, "epsg": frame.epsg, "zone": frame.zone, "offset": list(frame.offset),
                     "enu_to_frame": {**_similarity_record(frame.from_enu),
                                      "maps": "x_frame = scale * rotation @ x_enu + translation"},
                     "max_error_m": frame.max_error_m,
                     "what": "UTM coordinates = frame coordinates + offset; max_error_m: the largest error of "
                             "this similarity against pyproj's UTM over the capture's extent"}


def _apply_gcps(model, result: dict, gcps: GcpList, gcp_sigma: float) -> None:
    """Triangulate the GCPs in ``model`` and move it onto them (with the GPS photos that agree, when
    GPS placed it and the GCPs are on the Earth); the ``gcp`` record and the frame in ``result``."""
    seen, unused = [], {}
    for point in gcps.points:
        try:
            seen.append((point, triangulate(model, [(o.image, o.x, o.y) for o in point.observations])))
        except ControlError as exc:
            unused[point.name] = str(exc)
    with_gps = result["georeferenced"] and not gcps.local
    if gcps.local:
        origin, targets = None, np.array([p.position for p, _ in seen]).reshape(-1, 3)
    else:
        lla = to_wgs84(gcps.crs, np.array([p.position for p in gcps.points]))
        origin = (tuple(result["origin"][k] for k in ("lat", "lon", "alt")) if with_gps else
                  median_origin([dict(zip(("lat", "lon", "alt"), row)) for row in lla]))
        by_name = dict(zip((p.name for p in gcps.points), lla))
        targets = enu_from_wgs84(np.array([by_name[p.name] for p, _ in seen]).reshape(-1, 3), origin)
    anchors = _gps_anchors(model, result) if with_gps else None
    points = np.array([t.xyz for _, t in seen]).reshape(-1, 3)
    try:
        fit = align_to_control(points, targets, gcp_sigma, anchors)
    except GeorefError as exc:
        why = "; ".join(f"{name}: {reason}" for name, reason in unused.items())
        raise ControlError(f"gcp_file: the GCPs cannot place the model: {exc}" +
                           (f" (not used: {why})" if why else "")) from None
    _transform(model, fit.similarity)
    before = _model_to_frame(result) if with_gps else None
    after = fit.similarity if before is None else _compose(fit.similarity, before)
    if with_gps:
        _refresh_photos(model, result)
    else:
        gps_note = ("not used: the GCPs are in a local frame" if result["georeferenced"] else
                    f"not used: {result.pop('reason')}")
        for key in ("residuals_m", "inliers", "inlier_threshold", "position_std_m", "without_gps", "outliers"):
            result.pop(key, None)
        result.update({"georeferenced": True, "gps": gps_note, "photos": []})
    result.update({
        "crs": GCP_LOCAL_CRS if gcps.local else CRS,
        "origin": None if origin is None else dict(zip(("lat", "lon", "alt"), origin)),
        "model_to_enu": _similarity_record(after),
        "scale_source": "GCP",
        "scale_relative_std": None if np.isnan(fit.scale_std) else fit.scale_std,
        "gcp": _gcp_record(gcps, seen, targets, fit, gcp_sigma, unused, with_gps),
    })
    if not gcps.local:
        result["altitude"] = ALTITUDE_NOTE


def _gps_anchors(model, result: dict):
    """The GPS inlier photos as (camera centres, GPS ENU, sigma) for a joint fit."""
    inliers = [p for p in result["photos"] if p["inlier"]]
    centres = _centres(model)
    return (np.array([centres[p["name"]] for p in inliers]), np.array([p["gps_enu"] for p in inliers]),
            np.array([p["sigma_m"] for p in inliers]))


def _centres(model) -> dict[str, np.ndarray]:
    return {model.image(i).name: model.image(i).projection_center() for i in model.reg_image_ids()}


def _refresh_photos(model, result: dict) -> None:
    """The GPS photos' camera positions and residuals after the model moved again."""
    centres = _centres(model)
    for photo in result["photos"]:
        photo["camera_enu"] = centres[photo["name"]].tolist()
        photo["residual_m"] = float(np.linalg.norm(centres[photo["name"]] - np.asarray(photo["gps_enu"])))
    residuals = [p["residual_m"] for p in result["photos"] if p["inlier"]]
    result["residuals_m"].update(median=float(np.median(residuals)), p90=float(np.percentile(residuals, 90)))


def _gcp_record(gcps: GcpList, seen, targets, fit, gcp_sigma: float, unused: dict, with_gps: bool) -> dict:
    points = []
    for k, (point, tri) in enumerate(seen):
        points.append({
            "name": point.name, "position": point.position.tolist(), "target_enu": targets[k].tolist(),
            "model_enu": (targets[k] + fit.residuals[k]).tolist(), "residual_enu": fit.residuals[k].tolist(),
            "residual_m": float(np.linalg.norm(fit.residuals[k])),
            "check_m": None if np.isnan(fit.checks[k]) else float(fit.checks[k]),
            "inlier": bool(fit.inliers[k]), "photos": tri.photos,
            "reprojection_px": float(tri.reprojection_px.max()), "unregistered_photos": tri.unregistered})
    used = [p["residual_m"] for p in points if p["inlier"]]
    checks = [p["check_m"] for p in points if p["inlier"] and p["check_m"] is not None]
    return {
        "crs": gcps.crs, "sigma_m": gcp_sigma, "with_gps": with_gps,
        "inlier_threshold_m": CHI3_99 * gcp_sigma,
        "rms_m": float(np.sqrt(np.mean(np.square(used)))),
        "check_rms_m": float(np.sqrt(np.mean(np.square(checks)))) if checks else None,
        "what": "residual_m: distance between a GCP's surveyed position and its triangulation in the fitted "
                "model; check_m: the same in a fit without that GCP (an independent check)",
        "points": points, "outliers": [p["name"] for p in points if not p["inlier"]],
        "not_used": unused,
    }


def _apply_scale_bars(model, result: dict, bars: Sequence[ScaleBar]) -> None:
    """Measure each bar in ``model``; unless GCPs fixed the scale, scale the model so the bars have
    their lengths. The ``scale_bars`` record in ``result``."""
    ends = []
    for k, bar in enumerate(bars):
        if bar.length <= 0:
            raise ControlError(f"scale_bars[{k}].length: give the bar's length in metres")
        pair = []
        for end, marks in (("a", bar.a), ("b", bar.b)):
            try:
                pair.append(triangulate(model, [(m.photo, m.x, m.y) for m in marks]))
            except ControlError as exc:
                raise ControlError(f"scale_bars[{k}].{end}: {exc}") from None
        ends.append(pair)
    measured = np.array([np.linalg.norm(a.xyz - b.xyz) for a, b in ends])
    lengths = np.array([bar.length for bar in bars])
    if result["scale_source"] != "GCP":
        fit = fit_scale(measured, lengths)
        _set_scale(model, result, fit, "scale bar")
        measured = measured * fit.scale
    result["scale_bars"] = [
        {"length_m": float(bar.length), "model_length_m": float(d), "error_m": float(d - bar.length),
         "reprojection_px": float(max(a.reprojection_px.max(), b.reprojection_px.max())),
         "photos": sorted(set(a.photos) | set(b.photos))}
        for bar, d, (a, b) in zip(bars, measured, ends)]


def _set_scale(model, result: dict, fit: BarScale, source: str) -> None:
    """Scale ``model`` by ``fit.scale``: about the GPS inlier photos' centroid when GPS placed it (the
    position and rotation GPS fixed stay), about the origin otherwise; ``source`` fixed the scale."""
    centre = (np.mean([p["camera_enu"] for p in result["photos"] if p["inlier"]], axis=0)
              if result["georeferenced"] else np.zeros(3))
    step = Similarity(fit.scale, np.eye(3), (1 - fit.scale) * centre)
    _transform(model, step)
    if result["georeferenced"]:
        result["model_to_enu"] = _similarity_record(_compose(step, _model_to_frame(result)))
        _refresh_photos(model, result)
    else:
        result["model_scale"] = {"scale": fit.scale, "maps": "x = scale * x_model (about the origin)"}
    result["scale_source"] = source
    result["scale_relative_std"] = None if np.isnan(fit.relative_std) else fit.relative_std


def _apply_markers(model, result: dict, found: Found) -> None:
    """Triangulate the corners of the targets ``found`` in ``model`` and measure their known distances;
    unless GCPs, scale bars or an earlier kind of target fixed the scale, scale the model so they
    have their lengths (a scale from GPS alone they replace, as scale bars do). Appends the record of these targets to ``result["markers"]``:
    whether they set the scale, the scale they measure in the model before (known / model length,
    fitted over every distance; 1 when they agree with the scale already fixed) and its spread, and
    per target its distances, their RMS residual, its photos and largest reprojection error."""
    record = {"source": found.source, "option": found.option, "what": found.what, "photos_searched": found.photos,
              "photos_with_detections": found.photos_with_detections}
    seen, unused = [], {}
    for target in found.targets:
        try:
            seen.append((target, [triangulate(model, corner) for corner in target.corners]))
        except ControlError as exc:
            unused[target.name] = str(exc)
    if not seen:
        why = "; ".join(f"{name}: {reason}" for name, reason in unused.items())
        result.setdefault("markers", []).append(
            {**record, "used": False, "set_scale": False, "targets": [], "not_used": unused,
             "reason": found.problem or f"{found.option}: no target could be measured in the model ({why})"})
        return
    measured = [np.array([np.linalg.norm(points[i].xyz - points[j].xyz) for i, j, _ in target.edges])
                for target, points in seen]
    lengths = [np.array([length for _, _, length in target.edges]) for target, _ in seen]
    fit = fit_scale(np.concatenate(measured), np.concatenate(lengths))
    sets = result["scale_source"] in ("GPS", "none")
    if sets:
        _set_scale(model, result, fit, found.source)
        measured = [d * fit.scale for d in measured]
    result.setdefault("markers", []).append({
        **record, "used": True, "set_scale": sets, "scale": fit.scale,
        "scale_relative_std": None if np.isnan(fit.relative_std) else fit.relative_std,
        "edges": int(sum(len(d) for d in measured)),
        "what_scale": "known / model length of the targets' edges, fitted over all of them, in the model as it "
                      "was before they were measured (1: they agree with the scale already fixed)",
        "targets": [{"name": target.name, "photos": sorted({name for p in points for name in p.photos}),
                     "length_m": known.tolist(), "model_length_m": d.tolist(),
                     "residual_m": float(np.sqrt(np.mean(np.square(d - known)))),
                     "reprojection_px": float(max(p.reprojection_px.max() for p in points))}
                    for (target, points), d, known in zip(seen, measured, lengths)],
        "not_used": unused})


def _similarity_record(sim: Similarity) -> dict:
    return {"scale": sim.s, "rotation": np.asarray(sim.R).tolist(), "translation": np.asarray(sim.t).tolist(),
            "maps": "x_enu = scale * rotation @ x_model + translation (x_model: the mapper's frame)"}


def _model_to_frame(result: dict) -> Similarity:
    record = result["model_to_enu"]
    return Similarity(record["scale"], np.asarray(record["rotation"]), np.asarray(record["translation"]))


def _compose(second: Similarity, first: Similarity) -> Similarity:
    """``second`` after ``first``."""
    return Similarity(second.s * first.s, second.R @ first.R, second.s * second.R @ first.t + second.t)
