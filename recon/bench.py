"""``make bench``: recon against the reference measured in the same run, on the real photo sets.

Sparse: recon's sparse pipeline and COLMAP's own defaults through pycolmap (extract_features,
match_exhaustive, incremental_mapping with default options) on temple_ring and fountain_p11; one
table with seconds per stage, total, the ratio recon/COLMAP, registered images and pose AUC.
Machines are noisy: compare the ratio, not the seconds.

    python -m recon.bench [--only sparse] [--datasets DIR] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import shutil
import stat
import sys
import time
from pathlib import Path

import recon
from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.products import Published, SparseModel

SPARSE_SETS = ("temple_ring", "fountain_p11")
REPO = Path(__file__).resolve().parents[1]
SPARSE = SparseModel.MODELS  # the sparse section's name, and its output folder


def _poses(rec) -> dict:
    out = {}
    for image in rec.images.values():
        if image.has_pose:
            pose = image.cam_from_world()
            out[Path(image.name).name] = (pose.rotation.matrix(), pose.translation)
    return out


def colmap_defaults(images: Path, out: Path) -> tuple[dict[str, float], object]:
    """COLMAP's own defaults through pycolmap, timed per step; returns times and the largest model."""
    import pycolmap

    out.mkdir(parents=True)
    db = out / "database.db"
    t0 = time.perf_counter()
    pycolmap.extract_features(str(db), str(images))
    t1 = time.perf_counter()
    pycolmap.match_exhaustive(str(db))
    t2 = time.perf_counter()
    models = pycolmap.incremental_mapping(str(db), str(images), str(out / SparseModel.MODELS))
    t3 = time.perf_counter()
    best = max(models.values(), key=lambda r: r.num_reg_images()) if models else None
    return {"features": t1 - t0, "matching": t2 - t1, "sfm": t3 - t2}, best


def recon_sparse(images: Path, ws: Path) -> tuple[dict[str, float], object]:
    import pycolmap

    result = recon.run(REPO / "pipelines" / "sparse.yaml", images=str(images), workspace=str(ws))
    times = dict(result.seconds)
    return times, pycolmap.Reconstruction(str(Published(ws).model()))


def bench_sparse(datasets: Path, out: Path) -> list[dict]:
    from recon.logs import quiet_colmap

    quiet_colmap(out / "colmap-log.")
    rows = []
    for name in SPARSE_SETS:
        root = datasets / name
        if not root.is_dir():
            print(f"bench: {root} absent, skipped", file=sys.stderr)
            continue
        gt = load_cameras(root)
        for tool, fn in (("COLMAP defaults", colmap_defaults), ("recon", recon_sparse)):
            dest = out / name / tool.split()[0].lower()
            shutil.rmtree(dest, ignore_errors=True)
            times, model = fn(root / "images", dest)
            figures = pose_metrics(_poses(model), gt) if model is not None else \
                {"registered": 0, "total": len(gt), "auc@1": 0.0, "auc@3": 0.0, "auc@5": 0.0}
            rows.append({"dataset": name, "tool": tool, "times": times, "seconds": sum(times.values()),
                         "registered": figures["registered"], "images": figures["total"],
                         **{k: figures[k] for k in ("auc@1", "auc@3", "auc@5")}})
    return rows


def print_sparse(rows: list[dict]) -> None:
    stages = ["ingest", "features", "matching", "sfm", "export"]
    head = f"{'dataset':<13} {'tool':<16}" + "".join(f"{s:>9}" for s in stages) + \
        f"{'total':>8}{'ratio':>7}{'reg':>8}{'AUC@1':>7}{'AUC@3':>7}{'AUC@5':>7}"
    print(head)
    print("-" * len(head))
    reference = {r["dataset"]: r["seconds"] for r in rows if r["tool"] == "COLMAP defaults"}
    for r in rows:
        cells = "".join(f"{r['times'][s]:>9.1f}" if s in r["times"] else f"{'-':>9}" for s in stages)
        ratio = r["seconds"] / reference[r["dataset"]] if r["dataset"] in reference else float("nan")
        reg = f"{r['registered']}/{r['images']}"
        print(f"{r['dataset']:<13} {r['tool']:<16}{cells}{r['seconds']:>8.1f}{ratio:>7.2f}{reg:>8}"
              f"{r['auc@1']:>7.1f}{r['auc@3']:>7.1f}{r['auc@5']:>7.1f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m recon.bench")
    parser.add_argument("--only", choices=[SPARSE, "lowlight", "add_photos", "mvs", "dense", "wide", "scale", "quality"],
                        default=None,
                        help="one section; without it every section but scale (300 views, 1-2 h: make bench-scale) "
                             "and quality (the scene zoo, hours: make bench-quality)")
    parser.add_argument("--datasets", type=Path, default=recon.datasets_root())
    parser.add_argument("--out", type=Path, default=REPO / "bench_out")
    args = parser.parse_args(argv)
    if args.only != "quality" and not args.datasets.is_dir():
        print(f"bench: datasets folder {args.datasets} absent (set RECON_DATASETS)", file=sys.stderr)
        return 2
    from recon.logs import setup_console

    setup_console(-1)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.only in (None, SPARSE):
        print("== sparse: recon vs COLMAP defaults (same run; ratio = recon total / COLMAP total) ==")
        print_sparse(bench_sparse(args.datasets, args.out / SPARSE))
    if args.only in (None, "lowlight"):
        bench_lowlight(args.datasets, args.out / "lowlight")
    if args.only in (None, "add_photos"):
        from recon import add_photos_bench

        add_photos_bench.main(["--datasets", str(args.datasets), "--out", str(args.out / "add_photos")])
    if args.only in (None, "mvs"):
        from recon.mvs import bench as mvs_bench

        print("\n== mvs: recon's CPU PatchMatch, beside OpenMVS 2.3 DensifyPointCloud on fountain_p11 ==", flush=True)
        mvs_bench.main(["--cache", str(args.out / "mvs")])
    if args.only in (None, "dense"):
        bench_dense(args.out / "dense")
    if args.only in (None, "wide"):
        from recon import wide_bench

        wide_bench.main(["--out", str(args.out / "wide")])
    if args.only == "quality":
        from recon import quality_bench

        quality_bench.main(["--out", str(args.out)])
    if args.only == "scale":
        from recon import scale_bench

        scale_bench.main(["--out", str(args.out / "scale")])
    return 0


#: OpenMVS 2.3 (CPU) on a comparable 24-view synthetic scene, measured on these machines (issues 3 and 4)
OPENMVS = {"fused@0.002": 0.975, "fused@0.005": 0.994, "mesh@0.002": 0.937, "mesh@0.005": 0.996, "psnr": 27.9,
           "coverage": 0.997}


def bench_dense(out: Path) -> None:
    """Photos to textured mesh on a synthetic scene (24 views, 640x480, 4 held-out views): stage times,
    accuracy/completeness/F of the fused cloud and the mesh, masked PSNR of the textured and of the
    vertex-coloured mesh in the held-out views and the texture's coverage of them (as the zoo scores
    them: recon.quality_bench.holdout_texture); OpenMVS 2.3's figures beside."""
    from recon.quality_bench import holdout_texture
    from recon.synth import load_scene, render_scene

    scene_dir = out / "scene"
    if not (scene_dir / "gt" / "scene.json").exists():
        render_scene(scene_dir, views=24, width=640, height=480, seed=0, holdout=4)
    scene = load_scene(scene_dir)
    ws = out / "ws"
    shutil.rmtree(ws, ignore_errors=True)
    result = recon.run(REPO / "pipelines" / "full.yaml", images=str(scene_dir / "images"), workspace=str(ws))
    figures = recon.api.evaluate(ws, scene_dir)
    held_out = holdout_texture(ws, scene)
    times = ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items())
    print("\n== dense: synthetic scene, 24 views 640x480, photos to textured mesh (poses estimated) ==")
    print(f"stage seconds: {times}")
    print(f"{'':<16}{'F@0.2%':>8}{'F@0.5%':>8}{'acc@0.2%':>10}{'comp@0.2%':>11}   OpenMVS 2.3 F@0.2% / F@0.5%")
    for key in ("fused", "mesh"):
        m = figures[key]
        print(f"{key:<16}{m['fscore@0.002'] / 100:>8.3f}{m['fscore@0.005'] / 100:>8.3f}{m['accuracy@0.002']:>10.1f}"
              f"{m['completeness@0.002']:>11.1f}   {OPENMVS[key + '@0.002']:.3f} / {OPENMVS[key + '@0.005']:.3f}")
    nothing = float("nan")  # no PSNR where the mesh shows nothing of the held-out views' surface
    print(f"held-out views: textured {held_out.get('psnr', nothing):.2f} dB, vertex colours "
          f"{held_out.get('psnr_vertex_colours', nothing):.2f} dB, coverage {held_out['coverage']:.3f} "
          f"(OpenMVS 2.3 TextureMesh: {OPENMVS['psnr']} dB, coverage {OPENMVS['coverage']}); placed by recon "
          f"localize ({held_out['placed']} views): textured {held_out.get('psnr_placed', nothing):.2f} dB, vertex "
          f"colours {held_out.get('psnr_vertex_colours_placed', nothing):.2f} dB")
    photos = sum(p.stat().st_size for p in (scene_dir / "images").iterdir())
    print(f"workspace: {_bytes_on_disk(ws) / 1e6:.0f} MB besides the photos ({photos / 1e6:.1f} MB)")


def _bytes_on_disk(folder: Path) -> int:
    """Bytes of the regular files under ``folder``, each hard-linked file once, links not followed."""
    seen: dict[tuple[int, int], int] = {}
    for root, _, names in os.walk(folder):
        for name in names:
            st = os.lstat(os.path.join(root, name))
            if stat.S_ISREG(st.st_mode):
                seen[(st.st_dev, st.st_ino)] = st.st_size
    return sum(seen.values())


def bench_lowlight(datasets: Path, out: Path) -> None:
    """Issue 5, criterion 4: sparse vs lowlight pipelines on a darkened, low-contrast, noisy temple_ring."""
    import numpy as np
    import pycolmap
    from PIL import Image

    from recon.imaging.degrade import low_light

    root = datasets / "temple_ring"
    if not root.is_dir():
        print(f"bench: {root} absent, low-light skipped", file=sys.stderr)
        return
    dark = out / "dark"
    shutil.rmtree(out, ignore_errors=True)
    dark.mkdir(parents=True)
    for i, path in enumerate(sorted((root / "images").glob("*.png"))):
        Image.fromarray(low_light(np.asarray(Image.open(path).convert("RGB")), seed=i)).save(dark / path.name)
    gt = load_cameras(root)
    print("\n== low light: temple_ring darkened (gain 2^-2.5, gamma 1.5, noise 1.5 levels) ==")
    print(f"{'pipeline':<10}{'seconds':>9}{'reg':>8}{'AUC@1':>7}{'AUC@3':>7}{'AUC@5':>7}")
    for name in (SPARSE, "lowlight"):
        start = time.perf_counter()
        recon.run(REPO / "pipelines" / f"{name}.yaml", images=str(dark), workspace=str(out / name), until="sfm")
        seconds = time.perf_counter() - start
        f = pose_metrics(_poses(pycolmap.Reconstruction(str(Published(out / name).model()))), gt)
        print(f"{name:<10}{seconds:>9.1f}{f['registered']:>5}/{f['total']:<2}{f['auc@1']:>7.1f}{f['auc@3']:>7.1f}"
              f"{f['auc@5']:>7.1f}")


if __name__ == "__main__":
    sys.exit(main())
