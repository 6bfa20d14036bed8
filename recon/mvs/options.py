"""Options of recon's CPU PatchMatch multi-view stereo."""

from __future__ import annotations

from dataclasses import dataclass

from recon.options import opt


@dataclass(frozen=True)
class MVSOptions:
    """Depth and normal map estimation (PatchMatch) and its consistency filtering."""

    max_image_size: int = opt(1536, "longest side of the images depth maps are computed at (px); larger ones are downscaled", ge=32)
    max_sources: int = opt(8, "most source views per reference view", ge=1, le=32)
    top_k: int = opt(1, "the matching cost of a hypothesis is the mean over its K best source views; 1 (its best "
                        "source) rather than 2 or 3 finds surface that only two or three photos see (zoo, docs/DECISIONS.md)", ge=1, le=32)
    min_triangulation_angle: float = opt(3.0, "source views whose shared points are seen under a smaller angle (deg) do not count", ge=0.0, le=45.0)
    max_scale_ratio: float = opt(2.0, "source views seeing the shared points at a resolution differing by more than this factor are skipped", ge=1.0)
    depth_margin: float = opt(0.25, "depth range: 1st percentile of the view's own sparse point depths / (1 + margin) / near_reach to the farthest sparse point in its view * (1 + margin) * far_reach", ge=0.0, le=4.0)
    near_reach: float = opt(3.0, "the depth range starts this many times nearer than the view's own sparse points do: "
                                 "foreground no sparse point lies on (a tree or a bin in front of a walk's photos) "
                                 "is searched too (zoo, docs/DECISIONS.md)", ge=1.0, le=100.0)
    far_reach: float = opt(2.5, "the depth range ends this many times farther than the farthest sparse point in view: "
                                "far ground that few photos see at grazing angles has few or no sparse points "
                                "(zoo, docs/DECISIONS.md)", ge=1.0, le=100.0)
    window_radius: int = opt(5, "half size of the matching window (px at the working level)", ge=1, le=15)
    window_step: int = opt(2, "sampling stride inside the matching window (px); 2 reads a quarter of its pixels", ge=1, le=4)
    sigma_color: float = opt(0.1, "bilateral weight: intensity scale (intensities in [0, 1]); 0.1 rather than 0.2 keeps a window's weight on the pixels like its centre (zoo at 320x240: fused and mesh F@0.2 % up, docs/DECISIONS.md)", gt=0.0)
    sigma_spatial: float = opt(0.0, "bilateral weight: distance scale (px); 0 means the window radius", ge=0.0)
    narrow_sigma: float = opt(0.0, "cpu: the bilateral weight's distance scale (px) of a pixel whose window, so weighted, "
                                   "is textured narrow_snr times above the photo's noise near its centre; 0: sigma_spatial "
                                   "at every pixel. A plane fitted over a narrower window leans less behind a curved "
                                   "surface: 2 suits small curved objects that fill the photos (zoo fused F@0.2 %: "
                                   "turntable_black +.005, clutter +.004) and costs far ground seen at grazing angles "
                                   "(far_field -.007; docs/DECISIONS.md, session 53)", ge=0.0)
    narrow_snr: float = opt(3.0, "cpu: how many times the photo's noise (estimated per image) the intensities' standard "
                                 "deviation in a pixel's narrowed window must reach", gt=0.0)
    min_texture: float = opt(0.005, "pixels whose weighted intensity standard deviation in the window is below this get no depth; cpu: filtering applies it again to the window's pixels within sigma_color / 2 of the pixel's own intensity (a uniform side of an edge, as sky beside a pole, otherwise takes the edge's depth)", ge=0.0)
    pyramid_levels: int = opt(4, "most coarse-to-fine levels (1 = single scale); each halves the resolution", ge=1, le=8)
    pyramid_min_size: int = opt(160, "a coarser level is added only while its longest side stays >= this (px)", ge=16)
    iterations: int = opt(4, "propagation+refinement sweeps at the coarsest level (random start)", ge=1, le=50)
    upper_iterations: int = opt(1, "sweeps at each intermediate level, starting from the upsampled coarser planes", ge=0, le=50)
    fine_iterations: int = opt(1, "sweeps at the finest (full working resolution) level", ge=0, le=50)
    view_subset: bool = opt(True, "above the coarsest level, match each pixel only against the top_k views best for its upsampled plane")
    perturbation: float = opt(0.1, "initial refinement range: relative depth change and normal change (rad/pi); halves every sweep", gt=0.0, le=1.0)
    geometric: bool = opt(True, "run the geometric-consistency pass (photometric + reprojection cost) before filtering")
    geometric_iterations: int = opt(1, "sweeps of the geometric-consistency pass", ge=0, le=50)
    geometric_weight: float = opt(0.2, "weight of the reprojection error (px) in the geometric-consistency cost", ge=0.0)
    geometric_max_error: float = opt(3.0, "reprojection errors are capped at this value (px) inside the cost", gt=0.0)
    filter_max_cost: float = opt(0.6, "filtering: largest matching cost (1 - NCC, mean of the K best views) kept", gt=0.0, le=2.0)
    filter_min_consistent: int = opt(1, "filtering: a pixel is kept when at least this many source depth maps agree with it (fusion then asks fusion.min_num_pixels views of it); 1 rather than 2: zoo, docs/DECISIONS.md", ge=0)
    filter_unconfirmed_cost: float = opt(0.3, "cpu filtering: a pixel that fewer than filter_min_consistent source depth "
                                              "maps confirm is kept where its matching cost is at most this (0: never). "
                                              "Surface only two or three photos see, often at a grazing angle, is missing "
                                              "from their photometric maps, which the confirmation reads; a window matched "
                                              "this well is seldom wrong, and fusion still asks two views to agree (zoo: "
                                              "docs/DECISIONS.md)", ge=0.0, le=2.0)
    filter_max_reprojection: float = opt(1.0, "filtering: largest forward-backward reprojection error (px) for a source to agree", gt=0.0)
    filter_max_depth_error: float = opt(0.01, "filtering: largest distance, relative to depth, between a source's surface point and the pixel's plane for the source to agree", gt=0.0)
    filter_grazing_allowance: float = opt(3.0, "filtering (CPU backend): on a plane seen at a grazing angle from a source, the depth difference along its ray may exceed filter_max_depth_error by up to this factor (1: a plain depth difference)", ge=1.0)
    planar_fill: bool = opt(True, "cpu: fill each untextured region of a final depth map (one shade, inside the photo's "
                                   "border) with the plane of the depths around it where they surround it and fit one "
                                   "plane (recon.mvs.planar_fill): walls and box faces in flat paint get depth, sky and "
                                   "background running out of the photo never do (zoo plain_boxes: mesh F@0.2 % .939 -> "
                                   ".963, held-out texture 26.6 -> 31.8 dB; docs/DECISIONS.md)")
    clear_background: bool = opt(True, "cpu: drop the depths, within the matching window of a large untextured region "
                                        "running out of the photo (sky, a backdrop), of pixels in its shade: the plane of "
                                        "the surface beside it carried past its edge (recon.mvs.background; zoo: mesh F@0.2 % "
                                        "mean .930 -> .942, fence_poles .941 -> .974; docs/DECISIONS.md)")
    drop_fattened: bool = opt(True, "cpu: drop the depths near a depth edge whose pixel's intensity differs from what the "
                                    "sources confirming the depth show there: the foreground's depth the matching window "
                                    "carried onto the background beside a silhouette (recon.mvs.fattening; zoo: clutter "
                                    "held-out texture 25.29 -> 25.82 dB, mesh F@0.2 % .947 -> .949; docs/DECISIONS.md)")
    drop_at_infinity: bool = opt(True, "cpu: drop the depths whose sources match them no better than they match the "
                                       "plane at infinity: the sky, and whatever else shows no parallax "
                                       "(recon.mvs.at_infinity; zoo far_field: fused F@0.2 % .9591 -> .9629, its sky "
                                       "gone from the cloud; docs/DECISIONS.md)")
    ground_normal: bool = opt(True, "cpu: where the photos agree on an up direction (taken by hand or at eye height), "
                                    "each pixel also tests its plane turned to face it: the ground, seen at grazing "
                                    "angles, where random normals rarely land close (recon.mvs.ground_normal; zoo: "
                                    "fused F@0.2 % worst (walkaround) .863 -> .868, mean .9630 -> .9635; "
                                    "docs/DECISIONS.md)")
    num_threads: int = opt(0, "CPU threads for the kernels (0 = all cores)", ge=0)
    seed: int = opt(0, "random seed; results are identical for equal seeds and inputs, whatever the thread count", ge=0)
