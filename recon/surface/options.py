"""Options of meshing and texturing (they become the ``mesh`` and ``texture`` config sections)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from recon.options import opt


@dataclass(frozen=True)
class MeshOptions:
    """How a surface is built from fused points (Poisson, Delaunay) or depth maps (TSDF), then cleaned."""

    method: Literal["poisson", "tsdf", "delaunay"] = opt(
        "poisson", "poisson: screened Poisson on oriented fused points; tsdf: fuse depth maps; delaunay: graph cut "
                   "of the fused points' tetrahedra by the views' lines of sight (as OpenMVS); zoo mesh F@0.2 % mean .882 "
                   "against Poisson's .886, above it where the cloud has stray or weakly supported points, more "
                   "holes (docs/DECISIONS.md)")
    depth: int = opt(9, "Poisson's cells: 1.2 times the points' extent without their farthest 0.1 % per axis "
                        "/ 2^depth, at most 20 times the points' median spacing (recon.surface.poisson); delaunay "
                        "keeps one point per cell of that extent / 2^(depth + 1)", ge=5, le=13)
    point_weight: float = opt(4.0, "Poisson screening weight: higher follows the points more closely", ge=0.0)
    deterministic: bool = opt(True, "single-threaded Poisson: the same mesh from the same points (multi-threaded, "
                                    "its densities differ in the last digits, so trimming cuts other faces)")
    density_quantile: float = opt(0.05, "drop Poisson vertices whose point density is below this quantile and more "
                                        "than mesh.density_levels below the median's (0: no density trim)", ge=0.0, lt=1.0)
    density_levels: float = opt(2.0, "a vertex of the low-density quantile is dropped only where its points lie sparser "
                                     "than the median vertex's by more than this many octree levels (each: twice the "
                                     "spacing); an evenly sampled object keeps its whole surface, and a part of it seen "
                                     "a sixth as densely too (an untextured side whose depth maps hold its rims). 0: the "
                                     "quantile alone (zoo, docs/DECISIONS.md)", ge=0.0)
    bbox_margin: float = opt(0.02, "trim Poisson faces outside the points' box grown by this fraction of its size", ge=0.0)
    trim_distance: float = opt(4.0, "drop faces farther than this many Poisson cells from any input point (0: off)", ge=0.0)
    voxel_size: float = opt(0.0, "TSDF voxel size in scene units (0: voxel_fraction x scene extent)", ge=0.0)
    voxel_fraction: float = opt(0.002, "TSDF voxel size as a fraction of the scene extent estimated from the depth maps", gt=0.0, le=0.1)
    sdf_trunc_voxels: float = opt(4.0, "TSDF truncation distance in voxels", gt=1.0)
    min_views: float = opt(1.0, "TSDF: keep surface seen by at least this many depth maps (integration weight)", ge=0.0)
    depth_max_fraction: float = opt(0.0, "ignore depths beyond this fraction of the scene extent, 0: keep all", ge=0.0)
    min_component_fraction: float = opt(0.001, "drop connected pieces with less than this fraction of the total area", ge=0.0, lt=1.0)
    min_component_support: float = opt(0.15, "also drop pieces, all but the largest, with fewer fused points per unit area "
                                             "than this fraction of the whole mesh's: Poisson's bridges over stray points "
                                             "(zoo: stray pieces 0.01-0.12, true ones mostly 0.27-2.4; docs/DECISIONS.md). "
                                             "0: off; tsdf has no fused points", ge=0.0)
    target_faces: int = opt(250000, "decimate (quadric error) to at most this many faces (0: no decimation)", ge=0)


@dataclass(frozen=True)
class TextureOptions:
    """How a mesh gets a texture atlas from the undistorted photos."""

    max_texture_size: int = opt(8192, "largest atlas side in texels; patches are scaled down to fit", ge=256, le=16384)
    texel_scale: float = opt(1.5, "texels per photo pixel (1: copy photo pixels unresampled); 1.5 keeps the detail the "
                                  "mixed photos add and spares a second resampling blur when the texture is viewed "
                                  "(zoo: held-out PSNR up on 14 of 15 scenes against 1, docs/DECISIONS.md)",
                             gt=0.0, le=2.0)
    padding: int = opt(3, "gutter around each chart in texels (keeps bilinear and mip-map lookups off the background)", ge=1, le=32)
    smoothness: float = opt(1.0, "weight keeping neighbouring faces on one photo, relative to the data term", ge=0.0)
    min_view_cosine: float = opt(0.1, "ignore views seeing a face more obliquely than this cosine", ge=0.0, lt=1.0)
    border_margin: int = opt(2, "faces must project this many pixels inside the photo border", ge=0)
    expansion_cycles: int = opt(2, "alpha-expansion sweeps over all views in view selection", ge=0, le=20)
    photo_consistency: bool = opt(True, "drop, per face, views whose colour there disagrees with most of its views "
                                        "(a car or person in some photos only), after their exposure is evened out")
    colour_calibration: bool = opt(True, "even out the photos' exposure, white balance and vignetting before "
                                         "texturing, estimated from the colours they show of the same faces "
                                         "(recon.surface.texture.photometric)")
    mix_ratio: float = opt(0.5, "each texel: the quality-weighted mean of its face's chosen photo and the other "
                                "photos seeing it unobstructed at least this fraction as well (view quality: "
                                "projected area x sharpness); 0: the chosen photo alone; not with levelling, whose "
                                "corrections fit the chosen photos. Zoo: held-out PSNR up on 12 of 15 scenes "
                                "(docs/DECISIONS.md)", ge=0.0, lt=1.0)
    levelling: bool = opt(False, "global colour adjustment between patches (Lempitsky and Ivanov 2007); off by "
                                 "default: on the scene zoo it lowered held-out PSNR on 12 of 15 scenes (mean -0.66 dB; "
                                 "seams fall on creases, where the two photos' colours differ for reasons other than "
                                 "exposure) and raised it by 0.23 dB on the one with +-0.7 stops of exposure per photo "
                                 "(docs/DECISIONS.md)")
    levelling_weight: float = opt(10.0, "weight of the smoothness of the per-vertex colour corrections within a patch (seams weigh 1)", gt=0.0)
    seam_blending: bool = opt(True, "local blending of the remaining colour differences in a band along seams; "
                                    "seam edges under two texels long are left out (recon.surface.texture.blending)")
    blend_band: int = opt(8, "width of the seam blending band in texels", ge=1, le=64)
