"""Products: the typed contract between stages.

Each kind of artifact a stage makes is a class here. It owns its file names (spelled nowhere else),
the files that must exist when the stage commits (:attr:`Product.required`), the workspace links
that show it (:attr:`Product.publish`) and typed readers and writers. A stage declares the products
it ``requires`` and the one it ``produces``; the pipeline derives the stage graph from them, hands
a running stage its inputs as products (``ctx.input(SparseModel).model()``) and checks the
declared files at commit (docs/ARCHITECTURE.md, "Products").

A product is rooted at the output folder of the stage that made it; it reads and writes nothing
outside that folder.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, TypedDict

from recon.files import read_json, write_json

# ---------------------------------------------------------------------------------------------
# The photo listing (images.json): what ingest found, what preprocess made of it, what the
# features database holds. One schema for all three.


class CameraEntry(TypedDict, total=False):
    """A camera group: the photos that share intrinsics."""

    id: int
    model: str  # COLMAP camera model name
    width: int
    height: int
    focal: float  # pixels: the EXIF prior, or a default guess
    prior_focal: bool  # whether ``focal`` came from EXIF or a calibration (else a guess)
    params: list[float]  # COLMAP parameters of the pixels stages after preprocess see
    fixed: bool  # a calibration used as fixed: SfM refines no intrinsics


class ImageEntry(TypedDict, total=False):
    """One photo (or one merged exposure bracket)."""

    name: str  # path relative to the photo folder, '/'-separated
    width: int
    height: int
    camera: int  # CameraEntry id
    focal_px: float | None  # EXIF focal in pixels of this image, if any
    converted: bool  # written as an upright 8-bit copy (EXIF rotation, 16 bit, alpha)
    masked: bool  # preprocess found a mask for it
    sources: list[str]  # the bracket's photos, when several were merged
    gps: dict[str, Any] | None  # EXIF GPS / drone XMP, when present


class PhotoListing(TypedDict, total=False):
    images: list[ImageEntry]
    cameras: list[CameraEntry]
    skipped: list[str]  # files left out, with the reason
    duplicates: list[list[str]]  # names of identical photos
    ordered: bool  # video frames: matching pairs them sequentially
    calibrated: bool  # a calibration gave the intrinsics


class Product:
    """A kind of artifact, rooted at the output folder of the stage that makes it."""

    #: output-relative paths that exist whenever the stage completed
    required: ClassVar[tuple[str, ...]] = ()
    #: output-relative path -> the workspace path of the link that shows it
    publish: ClassVar[dict[str, str]] = {}
    #: what it holds, one entry per file or folder (``recon stages``)
    describe: ClassVar[tuple[str, ...]] = ()

    def __init__(self, root: Path | str):
        self.root = Path(root)

    def missing(self) -> list[str]:
        """Required files that are not there."""
        return [rel for rel in self.required if not (self.root / rel).exists()]

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.root})"


class _Listed(Product):
    """A product that carries the photo listing."""

    LISTING = "images.json"

    def listing(self) -> PhotoListing:
        data = read_json(self.root / self.LISTING)
        if data is None:
            raise FileNotFoundError(self.root / self.LISTING)
        return data

    def write_listing(self, listing: PhotoListing) -> None:
        write_json(self.root / self.LISTING, listing)


class Photos(_Listed):
    """ingest: the photos as the pipeline sees them (links to the originals, or upright 8-bit copies)."""

    required = ("images", _Listed.LISTING)
    publish = {"images": "images"}
    describe = ("images/", _Listed.LISTING)

    @property
    def images(self) -> Path:
        return self.root / "images"


class Calibration(Product):
    """calibrate: intrinsics and distortion from board photos (absent when nothing was calibrated)."""

    FILE = "intrinsics.json"
    describe = ("intrinsics.json",)

    def read(self) -> dict | None:
        """The calibration (model, width, height, params, use, rms, ...), or None."""
        return read_json(self.root / self.FILE)

    def write(self, data: dict) -> None:
        write_json(self.root / self.FILE, data)


class PreparedPhotos(_Listed):
    """preprocess: the images features see (every 2D operation applied), the geometric-only images
    dense work and colours use, the masks, and the listing with the output pixels' cameras."""

    required = ("images", "images_geometric", _Listed.LISTING)
    publish = {"images_geometric": "images", "masks": "masks"}
    describe = ("images/", "images_geometric/", "masks/", _Listed.LISTING)

    @property
    def images(self) -> Path:
        return self.root / "images"

    @property
    def geometric(self) -> Path:
        return self.root / "images_geometric"

    @property
    def masks(self) -> Path:
        return self.root / "masks"


class FeatureDatabase(_Listed):
    """features: SIFT per photo, and COLMAP's database holding them with the cameras."""

    ITEMS = "items.json"
    required = ("database.db", _Listed.LISTING, ITEMS)
    publish = {"database.db": "database.db"}
    describe = ("features/<image>.npz", "database.db", _Listed.LISTING, ITEMS)

    @property
    def database(self) -> Path:
        return self.root / "database.db"

    def features(self, name: str) -> Path:
        return self.root / "features" / f"{name}.npz"

    def item_keys(self) -> dict[str, str]:
        """Image name -> the key of its features in the item store (:mod:`recon.items`)."""
        return read_json(self.root / self.ITEMS) or {}

    def write_item_keys(self, keys: dict[str, str]) -> None:
        write_json(self.root / self.ITEMS, keys)


class MatchDatabase(Product):
    """matching: COLMAP's database with matches and verified two-view geometries; the pairs tried."""

    required = ("database.db", "pairs.txt")
    publish = {"database.db": "database.db"}
    describe = ("database.db", "pairs.txt")

    @property
    def database(self) -> Path:
        return self.root / "database.db"

    @property
    def pairs(self) -> Path:
        return self.root / "pairs.txt"


class SparseModel(Product):
    """sfm: every model the mapper built (``sparse/0`` the largest) and the registration report."""

    MODELS = "sparse"  # COLMAP's name for the folder of models, in a sparse and a dense workspace
    REPORT = "models.json"
    GEOREFERENCE = "georeference.json"
    required = (f"{MODELS}/0", REPORT)
    publish = {MODELS: MODELS, GEOREFERENCE: GEOREFERENCE}
    describe = (f"{MODELS}/<k>/{{cameras,images,points3D}}.bin", REPORT, GEOREFERENCE)

    @property
    def georeference(self) -> Path:
        """Where the model is on Earth, or why it could not be placed (``georeferenced``: false)."""
        return self.root / self.GEOREFERENCE

    def model(self, k: int = 0) -> Path:
        return self.root / self.MODELS / str(k)

    def report(self) -> dict:
        return read_json(self.root / self.REPORT) or {}

    def write_report(self, report: dict) -> None:
        write_json(self.root / self.REPORT, report)


class Exports(Product):
    """export: the model in COLMAP's text format, coloured points, nerfstudio's transforms.json."""

    publish = {"sparse_text": "sparse_text", "points.ply": "points.ply", "transforms.json": "transforms.json"}
    describe = ("sparse_text/", "points.ply", "transforms.json")

    @property
    def text_model(self) -> Path:
        return self.root / "sparse_text"

    @property
    def points(self) -> Path:
        return self.root / "points.ply"

    @property
    def transforms(self) -> Path:
        return self.root / "transforms.json"


class DenseScene(Product):
    """undistort: COLMAP's undistorted workspace (pinhole images and model, stereo configs)."""

    FOLDER = "dense"
    required = (f"{FOLDER}/images", f"{FOLDER}/{SparseModel.MODELS}")
    publish = {f"{FOLDER}/images": f"{FOLDER}/images",
               f"{FOLDER}/{SparseModel.MODELS}": f"{FOLDER}/{SparseModel.MODELS}"}
    describe = (f"{FOLDER}/images/", f"{FOLDER}/{SparseModel.MODELS}/",
                f"{FOLDER}/stereo/{{patch-match,fusion}}.cfg")

    @property
    def folder(self) -> Path:
        """The COLMAP dense workspace folder."""
        return self.root / self.FOLDER

    @property
    def images(self) -> Path:
        return self.folder / "images"

    @property
    def model(self) -> Path:
        return self.folder / SparseModel.MODELS

    @property
    def stereo_configs(self) -> Path:
        return self.folder / "stereo"

    @property
    def masks(self) -> Path:
        """``<image name>.png`` masks of the undistorted images (zero = not the subject), when the
        photos had masks (preprocess.mask_dir)."""
        return self.folder / "masks"

    def mask(self, name: str):
        """The undistorted mask of image ``name`` (True = use), or None."""
        from recon.imaging.masks import load_mask

        return load_mask(self.masks, name)

    def views(self) -> list:
        """The registered views' pinhole cameras, sorted by name (:func:`recon.mvs.views.model_views`)."""
        from recon.mvs.views import model_views

        return model_views(self.model)


class DepthMaps(Product):
    """mvs: per-view depth and normal maps in COLMAP's format: the final (geometric) ones, and the
    photometric ones and their source masks only with ``mvs.keep_photometric`` (no later stage reads them)."""

    required = ("stereo/depth_maps",)
    publish = {"stereo": "dense/stereo"}
    describe = ("stereo/depth_maps/<image>.geometric.bin", "stereo/normal_maps/<image>.geometric.bin",
                "stereo/{depth,normal}_maps/<image>.photometric.bin",
                "stereo/source_masks/<image>.photometric.npz")

    @property
    def folder(self) -> Path:
        """COLMAP's ``stereo`` folder (depth_maps/, normal_maps/)."""
        return self.root / "stereo"

    def depth_map(self, name: str, kind: str = "geometric") -> Path:
        return self.folder / "depth_maps" / f"{name}.{kind}.bin"

    def of_views(self, views: list):
        """(view, its final depth map) for each of ``views`` that has one, read one at a time."""
        from recon.mvs.colmap_io import read_depth_map

        for view in views:
            path = self.depth_map(view.name)
            if path.exists():
                yield view, read_depth_map(path)


class FusedCloud(Product):
    """fusion: the fused point cloud with normals and colours; with ``fusion.keep_visibility``, COLMAP's
    record of the views that saw each point (``fused.ply.vis``, which its Delaunay mesher reads); with
    ``fusion.mesh_reproj_error``, the cloud the mesh stage meshes (``meshing.ply``)."""

    required = ("fused.ply",)
    publish = {"fused.ply": "dense/fused.ply", "fused.ply.vis": "dense/fused.ply.vis"}
    describe = ("fused.ply", "fused.ply.vis", "meshing.ply")

    @property
    def path(self) -> Path:
        return self.root / "fused.ply"

    @property
    def meshing(self) -> Path:
        return self.root / "meshing.ply"

    def for_meshing(self) -> Path:
        """The cloud to mesh: ``meshing.ply`` where fusion made one, else ``fused.ply``."""
        return self.meshing if self.meshing.exists() else self.path

    @property
    def visibility(self) -> Path:
        return self.root / "fused.ply.vis"


class SurfaceMesh(Product):
    """mesh: the cleaned, decimated surface with vertex colours."""

    required = ("mesh.ply",)
    publish = {"mesh.ply": "mesh.ply"}
    describe = ("mesh.ply",)

    @property
    def path(self) -> Path:
        return self.root / "mesh.ply"


class TexturedModel(Product):
    """texture: the textured mesh as glTF binary and OBJ (+ MTL, PNG atlas), and a vertex-coloured PLY."""

    required = ("textured.glb",)
    publish = {"textured.glb": "textured.glb", "textured.obj": "textured.obj", "textured.mtl": "textured.mtl",
               "textured.png": "textured.png", "mesh.ply": "mesh.ply"}
    describe = ("textured.glb", "textured.obj", "textured.mtl", "textured.png", "mesh.ply")

    @property
    def glb(self) -> Path:
        return self.root / "textured.glb"

    @property
    def mesh(self) -> Path:
        """The textured mesh's geometry with vertex colours."""
        return self.root / "mesh.ply"


class Report(Product):
    """report: one self-contained HTML page."""

    required = ("report.html",)
    publish = {"report.html": "report.html"}
    describe = ("report.html",)

    @property
    def path(self) -> Path:
        return self.root / "report.html"


class Localization(Product):
    """localize: where new photos were taken (poses.json) and the reference model with them added."""

    required = ("poses.json",)
    publish = {"poses.json": "poses.json", SparseModel.MODELS: SparseModel.MODELS}
    describe = ("features/<image>.npz", "poses.json", "sparse/0/")

    @property
    def poses(self) -> Path:
        return self.root / "poses.json"

    def model(self) -> Path:
        return self.root / SparseModel.MODELS / "0"

    def features(self, name: str) -> Path:
        return self.root / "features" / f"{name}.npz"


class StereoDepth(Product):
    """stereo: depth of a rectified pair in the left photo's frame, a preview and a cloud."""

    required = ("stereo",)
    publish = {"stereo": "stereo"}
    describe = ("stereo/depth.{npy,bin}", "stereo/depth_preview.png", "stereo/cloud.ply",
                "stereo/calibration.json")

    @property
    def folder(self) -> Path:
        return self.root / "stereo"


class Panorama(Product):
    """panorama: the stitched image and its geometry."""

    required = ("panorama.jpg", "panorama.json")
    publish = {"panorama.jpg": "panorama.jpg", "panorama.json": "panorama.json"}
    describe = ("panorama.jpg", "panorama.json")


class Published:
    """The user-facing files of a workspace (the links the products publish), for readers that
    take a workspace rather than a stage output: ``recon eval``, the report, ``recon localize``."""

    def __init__(self, root: Path | str):
        self.root = Path(root)

    def model(self, k: int = 0) -> Path:
        return self.root / SparseModel.publish[SparseModel.MODELS] / str(k)

    @property
    def database(self) -> Path:
        return self.root / MatchDatabase.publish["database.db"]

    @property
    def dense(self) -> Path:
        """COLMAP's dense workspace folder (images/, sparse/, stereo/, fused.ply)."""
        return self.root / DenseScene.FOLDER

    @property
    def depth_maps(self) -> Path:
        return self.root / DepthMaps.publish["stereo"] / "depth_maps"

    @property
    def fused(self) -> Path:
        return self.root / FusedCloud.publish["fused.ply"]

    @property
    def mesh(self) -> Path:
        return self.root / SurfaceMesh.publish["mesh.ply"]

    @property
    def textured(self) -> Path:
        return self.root / TexturedModel.publish["textured.glb"]
