"""Synthetic scenes seen through fisheye and 360-degree (equirectangular) cameras, with ground truth.

- :func:`render_fisheye_orbit`: the synthetic scene (:mod:`recon.synth.scene`) from the usual orbit
  (:mod:`recon.synth.cameras`) through an equidistant fisheye lens (image radius = f x angle off the
  axis), about 176 degrees across the diagonal: COLMAP's ``OPENCV_FISHEYE`` with k1..k4 = 0.
- :func:`render_room_walk`: 2:1 equirectangular panoramas (COLMAP's ``EQUIRECTANGULAR``) taken
  walking through a room (:mod:`recon.synth.room`), the camera held upright within a few degrees.

Pixel rays come from pycolmap's own camera models (``Camera.cam_ray_from_img``), so the images
follow COLMAP's conventions exactly (pixel centres at half-integers; an equirectangular image's
centre looks along +z, its left and right edges backwards, its top row up, -y).

Files as :mod:`recon.synth.dataset` writes them (``images/``, ``gt/cameras.json``, ``gt/mesh.ply``,
``gt/scene.json`` written last), except that each frame of ``cameras.json`` also holds COLMAP's
``model`` and ``params``; its ``K`` holds the focal lengths and principal point of the fisheye, and
pixels per radian (W / 2 pi, H / pi) with the image centre for a panorama. ``gt/depth/<stem>.npy``
holds the DISTANCE along each pixel's ray (a panorama's rays point every way, so camera z would not
do), 0 where nothing is hit; ``scene.json`` says so (``"depth": "range"``). There are no normal maps.

Images are JPEG (q95). Fisheye photos carry no focal length unless ``lens_exif``: then EXIF
LensModel names a fisheye and FocalLengthIn35mmFilm is the crop-factor 35 mm equivalent (what
cameras write: f_px = f35 / 43.27 mm x the image diagonal in pixels, for any lens projection).
Panoramas carry the XMP GPano tags 360-degree cameras write (``GPano:ProjectionType="equirectangular"``).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path

import numpy as np
from PIL import ExifTags, Image

from recon.eval.groundtruth import Camera
from recon.synth.cameras import look_at, scene_cameras
from recon.synth.dataset import FILM_DIAGONAL_MM, JPEG_QUALITY, SceneInfo, _remove_previous, _write_mesh
from recon.synth.render import Renderer
from recon.synth.room import WALK, WALK_BEND, build_room
from recon.synth.scene import Scene, build_scene

log = logging.getLogger(__name__)

FISHEYE_DIAGONAL_FOV_DEG = 176.0
WALK_HEIGHT = 1.5  # camera height of the panoramas above the floor, metres


@dataclasses.dataclass(frozen=True)
class WideView:
    """One view: COLMAP camera model and parameters, world-to-camera pose, size."""

    model: str
    params: tuple[float, ...]
    width: int
    height: int
    R: np.ndarray
    t: np.ndarray

    def colmap(self):
        """The ``pycolmap.Camera`` of this view."""
        import pycolmap

        return pycolmap.Camera(model=self.model, width=self.width, height=self.height, params=list(self.params))

    @property
    def pixels_per_radian(self) -> float:
        return self.width / (2 * np.pi) if self.model == "EQUIRECTANGULAR" else float(self.params[0])

    @property
    def K(self) -> np.ndarray:
        """fx, fy, cx, cy as a 3x3 matrix (for a panorama: pixels per radian, image centre)."""
        if self.model == "EQUIRECTANGULAR":
            fx, fy, cx, cy = self.width / (2 * np.pi), self.height / np.pi, self.width / 2, self.height / 2
        else:
            fx, fy, cx, cy = self.params[:4]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    def to_json(self, name: str) -> dict:
        cam = Camera(self.K, self.R, self.t, self.width, self.height)
        return {**cam.to_json(name), "model": self.model, "params": [float(p) for p in self.params]}


def fisheye_params(width: int, height: int, diagonal_fov_deg: float = FISHEYE_DIAGONAL_FOV_DEG) -> tuple[float, ...]:
    """OPENCV_FISHEYE parameters of an equidistant lens spanning ``diagonal_fov_deg`` across the diagonal."""
    f = np.hypot(width, height) / 2 / np.radians(diagonal_fov_deg / 2)
    return (f, f, width / 2, height / 2, 0.0, 0.0, 0.0, 0.0)


def fisheye_orbit_views(views: int = 20, width: int = 640, height: int = 480, seed: int = 0,
                        diagonal_fov_deg: float = FISHEYE_DIAGONAL_FOV_DEG) -> dict[str, WideView]:
    """The fisheye views: the poses of :func:`recon.synth.scene_cameras`' orbit, a fisheye lens."""
    poses, _ = scene_cameras(views, width, height, seed, "orbit")
    params = fisheye_params(width, height, diagonal_fov_deg)
    return {name: WideView("OPENCV_FISHEYE", params, width, height, cam.R, cam.t) for name, cam in poses.items()}


def room_walk_views(views: int = 16, width: int = 1536, height: int = 768, seed: int = 0) -> dict[str, WideView]:
    """Panoramas along the room's walk: evenly spaced, bending sideways, at WALK_HEIGHT (+-5 cm), each
    turned to the walking direction +-20 degrees, tilted and rolled up to 3 degrees."""
    if width != 2 * height:
        raise ValueError(f"an equirectangular image is twice as wide as high, got {width}x{height}")
    rng = np.random.default_rng([seed, 8])
    start, end = WALK
    heading = (end - start) / np.linalg.norm(end - start)
    side = np.array([-heading[1], heading[0]])
    out = {}
    for i in range(views):
        s = i / max(views - 1, 1)
        xy = start + s * (end - start) + WALK_BEND * np.sin(np.pi * s) * side
        center = np.array([*xy, WALK_HEIGHT + rng.uniform(-0.05, 0.05)])
        yaw = np.arctan2(heading[1], heading[0]) + np.radians(rng.uniform(-20, 20))
        R_level, _ = look_at(center, center + [np.cos(yaw), np.sin(yaw), 0.0])
        R = _small_rotation(np.radians(rng.uniform(-3, 3, size=3))) @ R_level
        out[f"pano_{i:03d}.jpg"] = WideView("EQUIRECTANGULAR", (float(width), float(height)), width, height,
                                            R, -R @ center)
    return out


def _small_rotation(angles: np.ndarray) -> np.ndarray:
    """Rotation by the rotation vector ``angles`` (radians), Rodrigues' formula."""
    theta = np.linalg.norm(angles)
    if theta == 0:
        return np.eye(3)
    k = angles / theta
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * K + (1 - np.cos(theta)) * K @ K


def render_fisheye_orbit(out_dir: str | Path, views: int = 20, width: int = 640, height: int = 480, seed: int = 0,
                         diagonal_fov_deg: float = FISHEYE_DIAGONAL_FOV_DEG, lens_exif: bool = False) -> SceneInfo:
    """Render the fisheye orbit into ``out_dir`` (see the module doc) and return its :class:`SceneInfo`."""
    cams = fisheye_orbit_views(views, width, height, seed, diagonal_fov_deg)
    return _render(Path(out_dir), build_scene(seed), cams, seed, "fisheye_orbit",
                   lambda path, rgb, view: _write_fisheye(path, rgb, view, lens_exif))


def render_room_walk(out_dir: str | Path, views: int = 16, width: int = 1536, height: int = 768,
                     seed: int = 0) -> SceneInfo:
    """Render the room walk's panoramas into ``out_dir`` (see the module doc); its :class:`SceneInfo`."""
    return _render(Path(out_dir), build_room(seed), room_walk_views(views, width, height, seed), seed, "room_walk",
                   _write_panorama)


def render_view(renderer: Renderer, view: WideView, supersample: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, range float32 HxW: distance along the pixel's ray, 0 = nothing hit) of ``view``."""
    camera = view.colmap()
    rgb, distance, _ = renderer.render_rays(-view.R.T @ view.t, view.R, view.width, view.height,
                                            lambda px: camera.cam_ray_from_img(np.asarray(px, np.float64)),
                                            view.pixels_per_radian, supersample)
    return rgb, distance


def _render(out: Path, scene: Scene, cams: dict[str, WideView], seed: int, path: str, write_image) -> SceneInfo:
    start = time.perf_counter()
    renderer = Renderer(scene)
    gt = out / "gt"
    _remove_previous(out)
    for folder in (out / "images", gt / "depth"):
        folder.mkdir(parents=True, exist_ok=True)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for name, view in cams.items():
        rgb, distance = render_view(renderer, view)
        write_image(out / "images" / name, rgb, view)
        np.save(gt / "depth" / f"{Path(name).stem}.npy", distance)
        pts = range_points(distance, view)
        if len(pts):
            lo, hi = np.minimum(lo, pts.min(0)), np.maximum(hi, pts.max(0))
    (gt / "cameras.json").write_text(json.dumps({"frames": [v.to_json(n) for n, v in cams.items()]}, indent=1))
    _write_mesh(gt / "mesh.ply", scene.vertices, scene.faces, scene.normals)
    first = next(iter(cams.values()))
    bmin, bmax = scene.bbox
    info = SceneInfo(out, seed, len(cams), 0, first.width, first.height, path, "jpg",
                     tuple(float(v) for v in bmin), tuple(float(v) for v in bmax),
                     float(np.linalg.norm(hi - lo)) if np.isfinite(lo).all() else 0.0, tuple(cams), (), name=path)
    meta = {k: v for k, v in dataclasses.asdict(info).items() if k != "root"}
    meta.update(camera_model=first.model, depth="range",
                extent_definition="diagonal of the axis-aligned bounding box of the surface points the views see")
    (gt / "scene.json").write_text(json.dumps(meta, indent=1))
    log.info("rendered %d %s views %dx%d in %.2f s", len(cams), first.model, first.width, first.height,
             time.perf_counter() - start)
    return info


def load_views(root: str | Path) -> dict[str, WideView]:
    """The fisheye / equirectangular views of a scene written here, keyed by image name; empty for a
    pinhole scene (its ``cameras.json`` frames carry no ``model``)."""
    frames = json.loads((Path(root) / "gt" / "cameras.json").read_text())["frames"]
    return {f["name"]: WideView(f["model"], tuple(f["params"]), f["width"], f["height"], np.array(f["R"]),
                                np.array(f["t"])) for f in frames if "model" in f}


def range_points(distance: np.ndarray, view: WideView) -> np.ndarray:
    """World points of a range map's hit pixels (their centres' rays)."""
    v, u = np.nonzero(distance > 0)
    rays = view.colmap().cam_ray_from_img(np.column_stack([u + 0.5, v + 0.5]).astype(np.float64))
    return (rays * distance[v, u, None]) @ view.R - view.t @ view.R


def _write_fisheye(path: Path, rgb: np.ndarray, view: WideView, lens_exif: bool) -> None:
    exif = Image.Exif()
    exif[ExifTags.Base.Make] = "recon"
    exif[ExifTags.Base.Model] = "synthetic fisheye"
    if lens_exif:
        sub = exif.get_ifd(ExifTags.IFD.Exif)
        sub[ExifTags.Base.LensModel] = f"synthetic {FISHEYE_DIAGONAL_FOV_DEG:g} degree fisheye"
        sub[ExifTags.Base.FocalLengthIn35mmFilm] = round(view.params[0] / np.hypot(view.width, view.height)
                                                         * FILM_DIAGONAL_MM)
    Image.fromarray(rgb).save(path, format="JPEG", quality=JPEG_QUALITY, exif=exif)


def gpano_xmp(width: int, height: int) -> bytes:
    """The XMP packet a 360-degree camera writes into its equirectangular JPEGs (Google's GPano tags)."""
    return (
        '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:GPano="http://ns.google.com/photos/1.0/panorama/" '
        'GPano:ProjectionType="equirectangular" GPano:UsePanoramaViewer="True" '
        f'GPano:FullPanoWidthPixels="{width}" GPano:FullPanoHeightPixels="{height}" '
        f'GPano:CroppedAreaImageWidthPixels="{width}" GPano:CroppedAreaImageHeightPixels="{height}" '
        'GPano:CroppedAreaLeftPixels="0" GPano:CroppedAreaTopPixels="0"/></rdf:RDF></x:xmpmeta>').encode()


def _write_panorama(path: Path, rgb: np.ndarray, view: WideView) -> None:
    exif = Image.Exif()
    exif[ExifTags.Base.Make] = "recon"
    exif[ExifTags.Base.Model] = "synthetic 360"
    Image.fromarray(rgb).save(path, format="JPEG", quality=JPEG_QUALITY, exif=exif,
                              xmp=gpano_xmp(view.width, view.height))

