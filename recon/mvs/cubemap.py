"""A COLMAP dense workspace of cube-map faces, for a model of 360-degree (equirectangular) photos.

COLMAP's undistorter, and every dense stage, works on pinhole cameras. Each panorama becomes six
pinhole views of 90 degrees (front, right, back, left, up, down) from its centre, whose poses follow
exactly from the panorama's: face-from-world = face-from-panorama (a fixed rotation) x
panorama-from-world. Their pixels are resampled from the panorama (bilinear, through pycolmap's own
EQUIRECTANGULAR model) and the model's points keep their tracks, each observation moved to the face
that sees it; so the existing PatchMatch, fusion, meshing and texturing take the faces as photos.

Faces are square, ``size`` pixels, focal length size / 2 (principal point at the centre): at
size = W / pi the face centre samples the panorama at its own resolution (W / 2 pi pixels per radian).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.products import SparseModel

#: face name -> rotation face-from-panorama (rows: the face's right, down and forward axes in the
#: panorama camera's frame: x right, y down, z forward)
FACES = {
    "front": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
    "right": ((0, 0, -1), (0, 1, 0), (1, 0, 0)),
    "back": ((-1, 0, 0), (0, 1, 0), (0, 0, -1)),
    "left": ((0, 0, 1), (0, 1, 0), (-1, 0, 0)),
    "up": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
    "down": ((1, 0, 0), (0, 0, -1), (0, 1, 0)),
}
JPEG_QUALITY = 95


def is_spherical(model: Path) -> bool:
    """Whether the COLMAP model at ``model`` holds 360-degree cameras."""
    import pycolmap

    return any(camera.is_spherical() for camera in pycolmap.Reconstruction(str(model)).cameras.values())


def face_size(width: int, max_size: int = 0) -> int:
    """Face side for panoramas ``width`` wide (W / pi, the panorama's resolution at the face centre),
    at most ``max_size`` when given."""
    size = round(width / np.pi)
    return min(size, max_size) if max_size else size


def face_name(panorama: str, face: str) -> str:
    """The image name of a panorama's face: ``dir/pano.jpg`` -> ``dir/pano_front.jpg``."""
    path = Path(panorama)
    return (path.parent / f"{path.stem}_{face}.jpg").as_posix()


def write_cubemap_workspace(model: Path, images: Path, out: Path, max_size: int = 0) -> dict:
    """COLMAP's dense layout in ``out`` (``images/``, ``sparse/``, ``stereo/patch-match.cfg`` and
    ``fusion.cfg``) for the equirectangular model ``model`` whose photos are in ``images``."""
    import pycolmap

    rec = pycolmap.Reconstruction(str(model))
    panoramas = sorted((im for im in rec.images.values() if im.has_pose), key=lambda im: im.name)
    widths = {rec.cameras[im.camera_id].width for im in panoramas}
    size = face_size(max(widths), max_size)
    f = size / 2.0
    faces = pycolmap.Reconstruction()
    faces.add_camera_with_trivial_rig(pycolmap.Camera(model="PINHOLE", width=size, height=size,
                                                      params=[f, f, size / 2.0, size / 2.0], camera_id=1))
    rays = _face_rays(size)
    observations: dict[int, list[tuple[int, int]]] = {}  # 3D point id -> (face image id, point2D index)
    names = []
    (out / "images").mkdir(parents=True, exist_ok=True)
    for pano in panoramas:
        camera = rec.cameras[pano.camera_id]
        pixels = _read_bgr(images / pano.name)
        pose = pano.cam_from_world()
        R_pano, t_pano = pose.rotation.matrix(), np.asarray(pose.translation)
        seen = [(p.point3D_id, rec.points3D[p.point3D_id].xyz) for p in pano.points2D if p.has_point3D()]
        ids = np.array([s[0] for s in seen], dtype=np.int64)
        in_pano = (np.array([s[1] for s in seen]).reshape(-1, 3) @ R_pano.T) + t_pano
        for face, rows in FACES.items():
            R_face = np.array(rows, dtype=float)
            name = face_name(pano.name, face)
            image_id = len(names) + 1
            _write_jpeg(out / "images" / name, _resample(pixels, camera, rays @ R_face))
            x = in_pano @ R_face.T
            front = x[:, 2] > 1e-9
            uv = np.full((len(x), 2), -1.0)
            uv[front] = f * x[front, :2] / x[front, 2:3] + size / 2.0
            inside = front & np.all((uv >= 0) & (uv < size), axis=1)
            image = pycolmap.Image(name=name, camera_id=1, image_id=image_id,
                                   points2D=pycolmap.Point2DList([pycolmap.Point2D(xy) for xy in uv[inside]]))
            faces.add_image_with_trivial_frame(image, pycolmap.Rigid3d(pycolmap.Rotation3d(R_face @ R_pano),
                                                                       R_face @ t_pano))
            for k, point_id in enumerate(ids[inside]):
                observations.setdefault(int(point_id), []).append((image_id, k))
            names.append(name)
    for point_id, elements in observations.items():
        point = rec.points3D[point_id]
        new_id = faces.add_point3D(point.xyz, pycolmap.Track(), point.color)
        for image_id, k in elements:
            faces.add_observation(new_id, pycolmap.TrackElement(image_id, k))
    (out / SparseModel.MODELS).mkdir(parents=True, exist_ok=True)
    faces.write(str(out / SparseModel.MODELS))
    (out / "stereo").mkdir(parents=True, exist_ok=True)
    (out / "stereo" / "patch-match.cfg").write_text("".join(f"{n}\n__auto__, 20\n" for n in names))
    (out / "stereo" / "fusion.cfg").write_text("".join(f"{n}\n" for n in names))
    return {"images": len(names), "panoramas": len(panoramas), "size": f"{size}x{size}"}


def _face_rays(size: int) -> np.ndarray:
    """Face-camera rays (size*size, 3) of the pixel centres of a 90-degree face, row-major."""
    jj, ii = np.meshgrid(np.arange(size) + 0.5, np.arange(size) + 0.5)
    f = size / 2.0
    return np.column_stack([(jj.ravel() - f) / f, (ii.ravel() - f) / f, np.ones(size * size)])


def _resample(pixels: np.ndarray, camera, rays_pano: np.ndarray) -> np.ndarray:
    """The panorama's colours along panorama-camera rays (size*size, 3), as a square image."""
    import cv2

    size = int(round(np.sqrt(len(rays_pano))))
    uv = np.asarray(camera.img_from_cam(rays_pano / np.linalg.norm(rays_pano, axis=1, keepdims=True)))
    maps = (uv - 0.5).astype(np.float32).reshape(size, size, 2)  # OpenCV: pixel centres at integers
    maps[..., 1] = np.clip(maps[..., 1], 0, pixels.shape[0] - 1)  # wrap around in azimuth only
    return cv2.remap(pixels, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)


def _read_bgr(path: Path) -> np.ndarray:
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise OSError(f"{path}: cannot read image")
    return img  # BGR, written back as BGR


def _write_jpeg(path: Path, bgr: np.ndarray) -> None:
    import cv2

    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
        raise OSError(f"{path}: cannot write image")
