"""``python -m recon.bench --only add_photos``: photos added to a finished workspace (issue 18).

temple_ring with pipelines/sparse.yaml: all 47 photos from scratch; then, in another workspace,
40 of them, then the 7 others copied into the same folder and the same command run again. The 7
are every 7th photo by name, spread around the ring (photos that fill gaps). Held out as one arc
instead (the last 7 by name), the 40 split into separate models, the largest with 24 photos, and
the second run has 23 photos to register, not 7. Prints the seconds of each run, the ratio of the second run to the
from-scratch run (same process, same machine), registered photos, pose AUC, and what the second
run reused (features, pairs, the previous model).

    python -m recon.add_photos_bench [--datasets DIR] [--out DIR]
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
DATASET = "temple_ring"
ADDED = 7


def _run(images: Path, ws: Path) -> tuple[float, recon.pipeline.RunResult]:
    start = time.perf_counter()
    result = recon.run(REPO / "pipelines" / "sparse.yaml", images=str(images), workspace=str(ws))
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
    args = parser.parse_args(argv)
    print(f"\n== add photos: {DATASET}, all but {ADDED} photos, then those {ADDED} added (same command), "
          "vs all from scratch (ratio = seconds / from-scratch seconds) ==", flush=True)
    rows = bench_add_photos(args.datasets, args.out)
    if rows is not None:
        print_add_photos(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
