"""Write a synthetic scene to disk with its ground truth, and read it back.

Layout of ``out_dir``::

    images/view_000.jpg ...          the input photos (JPEG q95 with EXIF focal, or lossless PNG)
    holdout/images/holdout_000.jpg   views between the regular ones, for testing novel views
    gt/cameras.json                  {"frames": [{name, width, height, K, R, t}]} (COLMAP world-to-camera)
    gt/holdout_cameras.json          same, for the hold-out views
    gt/depth/<stem>.npy              HxW float32 camera z, 0 where the ray hits nothing
    gt/normal/<stem>.npy             HxWx3 float32 unit normals in the camera frame, facing it, 0 = none
    gt/mesh.ply                      the whole scene surface in world coordinates
    gt/scene.json                    parameters, bounding box, extent (written last: marks completion)

and for the zoo's scenes (recon.synth.zoo) that have them::

    masks/<image name>.png           the masked object's pixels (255) in each regular view (COLMAP's
    holdout/masks/<image name>.png   mask naming, as ``preprocess.mask_dir`` reads them), and its
    gt/object.ply                    surface alone
    gt/transient/<stem>.png          where a transient object (in some photos only, not part of the
                                     ground truth) covers the photo; depth and normals show the
                                     static scene behind it
    gt/geotags.json                  the GPS tag (lat, lon, alt, horizontal_error) written into each
                                     regular photo's EXIF (recon.synth.geotags), for scenes with GPS
    holdout/diffuse/<image name>     each hold-out view rendered without highlights, for scenes with
                                     glossy parts: the surface's own colour, the most a texture (one
                                     colour per surface point) can show of that view

``extent`` is the diagonal of the axis-aligned bounding box of the surface seen by the regular
views, i.e. of all points back-projected from their ground-truth depth maps (the parts of the ground
square no regular view sees do not count; hold-out views do not count). Accuracy thresholds such
as "0.2 % of the scene extent" are fractions of this length.

JPEG EXIF: Make "recon", Model "synthetic"; FocalLength in mm for a 36 mm wide sensor with
FocalPlaneX/YResolution and unit (cm) set so that FocalLength * resolution = fx in pixels exactly;
FocalLengthIn35mmFilm follows the EXIF standard (CIPA DC-008): fx scaled by 43.27 mm / image
diagonal, rounded to an integer (COLMAP's reading).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from PIL import ExifTags, Image, TiffImagePlugin

from recon.eval.groundtruth import Camera, load_cameras, write_cameras
from recon.imaging.masks import save_mask
from recon.synth.cameras import scene_cameras
from recon.synth.geotags import GeoTag, add_gps
from recon.synth.render import SKY, Background, Renderer
from recon.synth.scene import Scene, assemble, build_scene
from recon.synth.shapes import Part

log = logging.getLogger(__name__)

FORMATS = ("jpg", "png")
SENSOR_WIDTH_MM = 36.0  # width of the sensor the EXIF FocalLength is given for (a full-frame sensor)
FILM_DIAGONAL_MM = 43.27  # diagonal of the 36 x 24 mm frame: the EXIF/CIPA basis of FocalLengthIn35mmFilm
JPEG_QUALITY = 95


@dataclasses.dataclass(frozen=True)
class SceneInfo:
    """A rendered synthetic scene: where its files are and its numbers (see the module doc)."""

    root: Path
    seed: int
    views: int
    holdout: int
    width: int
    height: int
    path: str
    image_format: str
    bbox_min: tuple[float, float, float]
    bbox_max: tuple[float, float, float]
    extent: float
    image_names: tuple[str, ...]
    holdout_names: tuple[str, ...]
    name: str = ""  # the zoo scene's name; "" for the seeded scene of render_scene
    masked: bool = False  # masks of an object are shipped (masks/, holdout/masks/, gt/object.ply)
    transient_names: tuple[str, ...] = ()  # regular views that show the transient object

    @property
    def images_dir(self) -> Path:
        return self.root / "images"

    @property
    def holdout_images_dir(self) -> Path:
        return self.root / "holdout" / "images"

    @property
    def gt_dir(self) -> Path:
        return self.root / "gt"

    @property
    def cameras_path(self) -> Path:
        return self.gt_dir / "cameras.json"

    @property
    def holdout_cameras_path(self) -> Path:
        return self.gt_dir / "holdout_cameras.json"

    @property
    def depth_dir(self) -> Path:
        return self.gt_dir / "depth"

    @property
    def normal_dir(self) -> Path:
        return self.gt_dir / "normal"

    @property
    def mesh_path(self) -> Path:
        return self.gt_dir / "mesh.ply"

    @property
    def scene_json(self) -> Path:
        return self.gt_dir / "scene.json"

    @property
    def masks_dir(self) -> Path:
        return self.root / "masks"

    @property
    def holdout_masks_dir(self) -> Path:
        return self.root / "holdout" / "masks"

    @property
    def object_mesh_path(self) -> Path:
        return self.gt_dir / "object.ply"

    @property
    def holdout_diffuse_dir(self) -> Path:
        return self.root / "holdout" / "diffuse"

    @property
    def transient_dir(self) -> Path:
        return self.gt_dir / "transient"

    def cameras(self, holdout: bool = False) -> dict[str, Camera]:
        """Ground-truth cameras of the regular (or hold-out) views, keyed by image name."""
        return load_cameras(self.holdout_cameras_path if holdout else self.cameras_path)

    def depth(self, name: str) -> np.ndarray:
        """Ground-truth depth (HxW float32, camera z, 0 = none) of image ``name``."""
        return np.load(self.depth_dir / f"{Path(name).stem}.npy")

    def normal(self, name: str) -> np.ndarray:
        """Ground-truth normals (HxWx3 float32, camera frame, facing the camera) of image ``name``."""
        return np.load(self.normal_dir / f"{Path(name).stem}.npy")


def render_scene(out_dir: str | Path, views: int = 24, width: int = 640, height: int = 480, seed: int = 0,
                 path: str = "orbit", holdout: int = 0, image_format: str = "jpg") -> SceneInfo:
    """Render the synthetic scene for ``seed`` seen by ``views`` cameras (and ``holdout`` extra ones)
    into ``out_dir`` and return its :class:`SceneInfo`. Files of an earlier render there are replaced;
    ``gt/scene.json`` is written last, so its presence means the scene is complete."""
    if image_format not in FORMATS:
        raise ValueError(f"image_format must be one of {FORMATS}, got {image_format!r}")
    regular, held = scene_cameras(views, width, height, seed, path, holdout, image_format)
    return write_scene(out_dir, build_scene(seed), regular, held, seed=seed, path=path, image_format=image_format)


@dataclasses.dataclass(frozen=True, eq=False)
class Capture:
    """How a scene's photos are taken, beyond a clean render in front of the default sky.

    ``develop(rgb, index)``: what the camera does to regular view ``index``'s rendered image (exposure,
    noise, blur...; hold-out views stay clean: they are the reference the textures are scored on).
    ``transient``: parts standing in the regular views ``transient_views`` only; they are no part of
    the ground truth (mesh, depth, normals, hold-out views). ``masked``: names of the parts that
    make the masked object. ``geotags``: GPS tags written into the EXIF of those regular views
    (JPEG only; :mod:`recon.synth.geotags`), recorded in ``gt/geotags.json``."""

    background: Background = dataclasses.field(default_factory=lambda: SKY)
    develop: Callable[[np.ndarray, int], np.ndarray] | None = None
    jpeg_quality: int = JPEG_QUALITY
    transient: tuple[Part, ...] = ()
    transient_views: frozenset[int] = frozenset()
    masked: frozenset[str] = frozenset()
    geotags: dict[str, GeoTag] = dataclasses.field(default_factory=dict)


def write_scene(out_dir: str | Path, scene: Scene, regular: dict[str, Camera], held: dict[str, Camera], *,
                seed: int, path: str, image_format: str = "jpg", name: str = "",
                capture: Capture = Capture()) -> SceneInfo:
    """Render ``scene`` into the cameras ``regular`` and ``held`` (hold-out) and write the layout of the
    module doc into ``out_dir``; ``seed``, ``path`` and ``name`` are recorded in ``gt/scene.json``."""
    start = time.perf_counter()
    out = Path(out_dir)
    renderer = Renderer(scene, capture.background)
    with_transient = Renderer(assemble([*scene.parts, *capture.transient]), capture.background) \
        if capture.transient and capture.transient_views else None
    diffuse = Renderer(assemble([dataclasses.replace(p, gloss=0.0) for p in scene.parts]), capture.background) \
        if held and any(p.gloss for p in scene.parts) else None
    masked_ids = [i for i, p in enumerate(scene.parts) if p.name in capture.masked]
    gt = out / "gt"
    _remove_previous(out)
    for folder in (out / "images", gt / "depth", gt / "normal", *([out / "holdout" / "images"] if held else []),
                   *([out / "holdout" / "diffuse"] if diffuse else [])):
        folder.mkdir(parents=True, exist_ok=True)
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    transient_names = []
    for cams, root in ((regular, out), (held, out / "holdout")):
        for index, (image_name, cam) in enumerate(cams.items()):
            rgb, depth, normal = renderer.render(cam)
            stem = Path(image_name).stem
            if cams is regular and with_transient is not None and index in capture.transient_views:
                rgb = with_transient.render(cam)[0]
                cover = with_transient.part_ids(cam) >= len(scene.parts)
                save_mask(gt / "transient", stem, cover)
                transient_names.append(image_name)
            if cams is regular and capture.develop is not None:
                rgb = capture.develop(rgb, index)
            quality = capture.jpeg_quality if cams is regular else JPEG_QUALITY
            _write_image(root / "images" / image_name, rgb, cam, image_format, quality,
                         capture.geotags.get(image_name) if cams is regular else None)
            if cams is held and diffuse is not None:
                _write_image(root / "diffuse" / image_name, diffuse.render(cam)[0], cam, image_format, quality)
            np.save(gt / "depth" / f"{stem}.npy", depth)
            np.save(gt / "normal" / f"{stem}.npy", normal)
            if masked_ids:
                save_mask(root / "masks", image_name, np.isin(renderer.part_ids(cam), masked_ids))
            if cams is regular:
                pts = _backproject(depth, cam)
                if len(pts):
                    lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
    write_cameras(gt / "cameras.json", regular)
    if capture.geotags:
        (gt / "geotags.json").write_text(json.dumps({n: dataclasses.asdict(t) for n, t in capture.geotags.items()},
                                                    indent=1))
    if held:
        write_cameras(gt / "holdout_cameras.json", held)
    _write_mesh(gt / "mesh.ply", scene.vertices, scene.faces, scene.normals)
    if masked_ids:
        obj = np.isin(scene.face_part, masked_ids)
        used, faces = np.unique(scene.faces[obj], return_inverse=True)
        _write_mesh(gt / "object.ply", scene.vertices[used], faces.reshape(-1, 3), scene.normals[used])
    bmin, bmax = scene.bbox
    first = next(iter(regular.values()))
    info = SceneInfo(out, seed, len(regular), len(held), first.width, first.height, path, image_format,
                     tuple(float(v) for v in bmin), tuple(float(v) for v in bmax),
                     float(np.linalg.norm(hi - lo)) if np.isfinite(lo).all() else 0.0,
                     tuple(regular), tuple(held), name, bool(masked_ids), tuple(transient_names))
    meta = {k: v for k, v in dataclasses.asdict(info).items() if k != "root"}
    meta["extent_definition"] = ("diagonal of the axis-aligned bounding box of the surface points "
                                 "back-projected from the regular views' ground-truth depth maps")
    (gt / "scene.json").write_text(json.dumps(meta, indent=1))
    log.info("rendered %s: %d+%d views %dx%d, seed %d, in %.2f s", name or "the seeded scene", len(regular),
             len(held), first.width, first.height, seed, time.perf_counter() - start)
    return info


def load_scene(path: str | Path) -> SceneInfo:
    """Read a scene written by :func:`render_scene` (its folder, or its ``gt/scene.json``)."""
    path = Path(path)
    meta_path = path if path.is_file() else path / "gt" / "scene.json"
    if not meta_path.is_file():
        raise FileNotFoundError(f"no synthetic scene at {path} (missing {meta_path})")
    meta = json.loads(meta_path.read_text())
    fields = {f.name for f in dataclasses.fields(SceneInfo)}
    kw = {k: v for k, v in meta.items() if k in fields}
    for k in ("bbox_min", "bbox_max", "image_names", "holdout_names", "transient_names"):
        if k in kw:
            kw[k] = tuple(kw[k])
    return SceneInfo(root=meta_path.parent.parent, **kw)


def _remove_previous(out: Path) -> None:
    """Delete the files an earlier render_scene wrote here (scene.json first: an interrupted render
    must not look complete), so a render with fewer views leaves no stale images behind."""
    patterns = ("gt/scene.json", "gt/cameras.json", "gt/holdout_cameras.json", "gt/mesh.ply", "gt/depth/*.npy",
                "gt/normal/*.npy", "images/view_*.jpg", "images/view_*.png", "holdout/images/holdout_*.jpg",
                "holdout/images/holdout_*.png", "gt/object.ply", "gt/transient/*.png", "masks/view_*.png",
                "holdout/masks/holdout_*.png", "gt/geotags.json", "holdout/diffuse/holdout_*.jpg",
                "holdout/diffuse/holdout_*.png")
    for pattern in patterns:
        for f in out.glob(pattern):
            f.unlink()


def _backproject(depth: np.ndarray, cam: Camera) -> np.ndarray:
    """World points of the valid pixels of a depth map (pixel centres, COLMAP convention)."""
    v, u = np.nonzero(depth > 0)
    z = depth[v, u].astype(np.float64)
    return cam.backproject(np.column_stack([u + 0.5, v + 0.5]), z)


def _write_image(path: Path, rgb: np.ndarray, cam: Camera, image_format: str, quality: int = JPEG_QUALITY,
                 geotag: GeoTag | None = None) -> None:
    img = Image.fromarray(rgb)
    if image_format == "png":
        img.save(path, format="PNG")
        return
    focal_mm = cam.K[0, 0] / cam.width * SENSOR_WIDTH_MM
    exif = Image.Exif()
    exif[ExifTags.Base.Make] = "recon"
    exif[ExifTags.Base.Model] = "synthetic"
    sub = exif.get_ifd(ExifTags.IFD.Exif)
    sub[ExifTags.Base.FocalLength] = TiffImagePlugin.IFDRational(round(focal_mm * 1000), 1000)
    # CIPA DC-008 defines the 35 mm equivalent by the image DIAGONAL (COLMAP reads it that way:
    # f_px = f35 / 43.27 * diagonal_px); it is an integer, so it is only a prior within ~2 %
    diagonal = float(np.hypot(cam.width, cam.height))
    sub[ExifTags.Base.FocalLengthIn35mmFilm] = round(cam.K[0, 0] / diagonal * FILM_DIAGONAL_MM)
    # the sensor resolution turns FocalLength into pixels exactly: width px per 3.6 cm
    sub[ExifTags.Base.FocalPlaneXResolution] = TiffImagePlugin.IFDRational(cam.width * 10, round(SENSOR_WIDTH_MM))
    sub[ExifTags.Base.FocalPlaneYResolution] = TiffImagePlugin.IFDRational(cam.width * 10, round(SENSOR_WIDTH_MM))
    sub[ExifTags.Base.FocalPlaneResolutionUnit] = 3  # centimetres
    sub[ExifTags.Base.ExifImageWidth] = cam.width
    sub[ExifTags.Base.ExifImageHeight] = cam.height
    if geotag is not None:
        add_gps(exif, geotag)
    img.save(path, format="JPEG", quality=quality, exif=exif)


def _write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray) -> None:
    import trimesh

    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, vertex_normals=normals, process=False)
    path.write_bytes(trimesh.exchange.ply.export_ply(mesh, encoding="binary", include_attributes=False))
