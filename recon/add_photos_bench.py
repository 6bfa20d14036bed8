"""``python -m recon.bench --only add_photos``: photos added to a finished workspace (issue 18).

temple_ring with pipelines/sparse.yaml: all 47 photos from scratch; then, in another workspace,
40 of them, then the 7 others copied into the same folder and the same command run again. The 7
are every 7th photo by name, spread around the ring (photos that fill gaps). Held out as one arc
instead (the last 7 by name), the 40 split into separate models, the largest with 24 photos, and
the second run has 23 photos to register, not 7. Prints the seconds of each run, the ratio of the second run to the
from-scratch run (same process, same machine), registered photos, pose AUC, and what the second
run reused (features, pairs, the previous model).

Then the same with pipelines/full.yaml on the zoo's ``classic`` scene (24 views at the zoo's size,
640x480, or ``--size``): 20 views, then every 6th view added, against all 24 from scratch; the
fused cloud's and the mesh's F-scores at 0.2 % and 0.5 % of the scene's extent, and the depth maps
the second run reused. The smaller the photos, the larger the share of the whole-model stages
(mesh, texture, report) that the second run repeats.

    python -m recon.add_photos_bench [--datasets DIR] [--out DIR] [--only temple|zoo] [--size WxH]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import time
from pathlib import Path

import recon
from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.products import Published

REPO = Path(__file__).resolve().parents[1]
PIPELINES = Path(__file__).resolve().parent / "pipelines"
DATASET = "temple_ring"
ADDED = 7
ZOO_SCENE, ZOO_VIEWS, ZOO_ADDED, ZOO_SIZE = "classic", 24, 4, (640, 480)
TAUS = ("0.002", "0.005")


def _run(images: Path, ws: Path, config: Path = PIPELINES / "sparse.yaml") -> tuple[float, recon.pipeline.RunResult]:
    start = time.perf_counter()
    result = recon.run(config, images=str(images), workspace=str(ws))
    return time.perf_counter() - start, result


def _figures(ws: Path, gt: dict) -> dict:
    import pycolmap

    rec = pycolmap.Reconstruction(str(Published(ws).model()))
    poses = {}
    for image in rec.images.values():
        if image.has_pose:
            pose = image.cam_from_world()
            poses[Path(image.name).name] = (pose.rotation.matrix(), pose.translation)
    return pose_metrics(poses, gt)


def bench_add_photos(datasets: Path, out: Path) -> dict | None:
    """The three runs; their seconds, figures and the second run's summaries."""
    root = datasets / DATASET
    if not root.is_dir():
        print(f"bench: {root} absent, add_photos skipped", file=sys.stderr)
        return None
    shutil.rmtree(out, ignore_errors=True)
    photos = sorted(p for p in (root / "images").iterdir() if p.is_file())
    gt = load_cameras(root)
    rows = {}
    seconds, _ = _run(root / "images", out / "scratch")
    rows["from scratch"] = {"seconds": seconds, **_figures(out / "scratch", gt)}
    added = photos[len(photos) // ADDED // 2::len(photos) // ADDED][:ADDED]
    images = out / "images"
    images.mkdir(parents=True)
    for photo in photos:
        if photo not in added:
            shutil.copy2(photo, images / photo.name)
    seconds, _ = _run(images, out / "added")
    rows[f"{len(photos) - ADDED} photos"] = {"seconds": seconds, **_figures(out / "added", gt)}
    for photo in added:
        shutil.copy2(photo, images / photo.name)
    seconds, result = _run(images, out / "added")
    rows[f"{ADDED} added"] = {"seconds": seconds, "stages": result.seconds,
                                           "summaries": result.summaries, **_figures(out / "added", gt)}
    return rows


def bench_zoo(out: Path, size: tuple[int, int] = ZOO_SIZE) -> dict:
    """The zoo scene's three runs (module doc) at ``size``: seconds, F-scores, the second run's summaries."""
    from recon.eval.workspace import evaluate
    from recon.synth.zoo import render_zoo

    shutil.rmtree(out, ignore_errors=True)
    scene = render_zoo(ZOO_SCENE, out / "scene", views=ZOO_VIEWS, width=size[0], height=size[1])
    photos = sorted(p for p in scene.images_dir.iterdir() if p.is_file())
    step = len(photos) // ZOO_ADDED
    added = photos[step // 2::step][:ZOO_ADDED]
    images = out / "images"
    images.mkdir()
    for photo in photos:
        if photo not in added:
            shutil.copy2(photo, images / photo.name)
    rows = {}

    def figures(ws: Path) -> dict:
        f = evaluate(ws, scene.root)
        return {**{f"{k}@{t}": f[k][f"fscore@{t}"] / 100 for k in ("fused", "mesh") for t in TAUS},
                "registered": f["poses"]["registered"], "total": len(photos)}

    seconds, _ = _run(scene.images_dir, out / "scratch", PIPELINES / "full.yaml")
    rows["from scratch"] = {"seconds": seconds, **figures(out / "scratch")}
    seconds, _ = _run(images, out / "added", PIPELINES / "full.yaml")
    rows[f"{len(photos) - ZOO_ADDED} views"] = {"seconds": seconds, **figures(out / "added")}
    for photo in added:
        shutil.copy2(photo, images / photo.name)
    seconds, result = _run(images, out / "added", PIPELINES / "full.yaml")
    rows[f"{ZOO_ADDED} added"] = {"seconds": seconds, "stages": result.seconds, "summaries": result.summaries,
                                  **figures(out / "added")}
    return rows


def print_zoo(rows: dict) -> None:
    scratch = rows["from scratch"]["seconds"]
    cols = [f"{k}@{t}" for k in ("fused", "mesh") for t in TAUS]
    print(f"{'run':<16}{'seconds':>9}{'ratio':>7}{'reg':>8}" + "".join(f"{'F ' + c:>16}" for c in cols))
    for name, r in rows.items():
        print(f"{name:<16}{r['seconds']:>9.1f}{r['seconds'] / scratch:>7.2f}{r['registered']:>5}/{r['total']:<2}"
              + "".join(f"{r[c]:>16.3f}" for c in cols))
    last = list(rows.values())[-1]
    print(f"second run, seconds per stage: {', '.join(f'{k} {v:.1f}' for k, v in last['stages'].items())}")
    mvs = last["summaries"].get("mvs", {})
    print(f"second run: final depth maps of {mvs.get('reused', 0)} of {mvs.get('views', 0)} views reused, "
          f"{mvs.get('computed', 0)} computed ({mvs.get('photometric_computed', 0)} photometric passes, "
          f"{mvs.get('photometric_reused', 0)} from earlier photometric maps); "
          f"sfm: {last['summaries']['sfm']['mapping']}")


def print_add_photos(rows: dict) -> None:
    scratch = rows["from scratch"]["seconds"]
    print(f"{'run':<16}{'seconds':>9}{'ratio':>7}{'reg':>8}{'AUC@1':>7}{'AUC@3':>7}{'AUC@5':>7}")
    for name, r in rows.items():
        print(f"{name:<16}{r['seconds']:>9.1f}{r['seconds'] / scratch:>7.2f}{r['registered']:>5}/{r['total']:<2}"
              f"{r['auc@1']:>7.1f}{r['auc@3']:>7.1f}{r['auc@5']:>7.1f}")
    last = list(rows.values())[-1]
    stages = ", ".join(f"{k} {v:.1f}" for k, v in last["stages"].items())
    s = last["summaries"]
    print(f"second run, seconds per stage: {stages}")
    print(f"second run reused: features of {s['features']['reused']} of {s['features']['images']} photos, "
          f"{s['matching']['reused_pairs']} of {s['matching']['pairs']} pairs; sfm: {s['sfm']['mapping']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m recon.add_photos_bench")
    parser.add_argument("--datasets", type=Path, default=recon.datasets_root())
    parser.add_argument("--out", type=Path, default=REPO / "bench_out" / "add_photos")
    parser.add_argument("--only", choices=["temple", "zoo"])
    parser.add_argument("--size", type=lambda v: tuple(int(x) for x in v.lower().split("x")), default=ZOO_SIZE,
                        help="zoo scene size, WxH (default 640x480)")
    args = parser.parse_args(argv)
    if args.only in (None, "temple"):
        print(f"\n== add photos: {DATASET}, all but {ADDED} photos, then those {ADDED} added (same command), "
              "vs all from scratch (ratio = seconds / from-scratch seconds) ==", flush=True)
        rows = bench_add_photos(args.datasets, args.out / DATASET)
        if rows is not None:
            print_add_photos(rows)
    if args.only in (None, "zoo"):
        print(f"\n== add photos, full pipeline: zoo scene {ZOO_SCENE} ({args.size[0]}x{args.size[1]}), "
              f"{ZOO_VIEWS - ZOO_ADDED} views, then {ZOO_ADDED} added, vs all {ZOO_VIEWS} from scratch ==", flush=True)
        print_zoo(bench_zoo(args.out / f"{ZOO_SCENE}_{args.size[0]}x{args.size[1]}", args.size))
    return 0


if __name__ == "__main__":
    sys.exit(main())
