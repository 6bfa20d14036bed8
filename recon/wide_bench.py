"""``make bench``'s fisheye and 360-degree section: recon beside COLMAP's defaults on two rendered sets.

- ``fisheye_orbit``: 20 views, 640 x 480, an equidistant fisheye 176 degrees across the diagonal, no
  focal length in EXIF (:func:`recon.synth.wide.render_fisheye_orbit`). COLMAP's defaults with the
  camera model set to OPENCV_FISHEYE (nothing else), COLMAP given the exact focal length too (what a
  user who knows it gets), recon with ``ingest.camera_model: OPENCV_FISHEYE``, and recon with its
  default pinhole model (the wrong model: registered, wrong, and warned about).
- ``room_walk``: 16 equirectangular panoramas, 1536 x 768, taken walking through a room
  (:func:`recon.synth.wide.render_room_walk`). COLMAP's defaults with EQUIRECTANGULAR; recon with
  ``ingest.camera_model: auto`` (the photos' GPano tags say 360).

Scenes are rendered once into ``--out`` and reused. Columns: seconds, registered photos, pose AUC.

    python -m recon.wide_bench [--out DIR]
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

import recon
from recon.eval.groundtruth import load_cameras
from recon.eval.poses import pose_metrics
from recon.products import Published, SparseModel
from recon.synth import load_scene
from recon.synth.wide import fisheye_params, render_fisheye_orbit, render_room_walk

REPO = Path(__file__).resolve().parents[1]


def scene(out: Path, name: str) -> Path:
    """The rendered set ``name`` under ``out`` (rendered when absent)."""
    root = out / name
    if not (root / "gt" / "scene.json").exists():
        if name == "fisheye_orbit":
            render_fisheye_orbit(root, views=20, width=640, height=480)
        else:
            render_room_walk(root, views=16, width=1536, height=768)
    return root


def colmap_run(images: Path, out: Path, model: str, params: list[float] | None = None) -> tuple[float, object]:
    """COLMAP's defaults through pycolmap (one camera, ``model``, ``params`` if given): seconds, largest model."""
    import pycolmap

    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = model
    if params is not None:
        reader.camera_params = ",".join(f"{p:.6f}" for p in params)
    start = time.perf_counter()
    pycolmap.extract_features(str(out / "database.db"), str(images), camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader)
    pycolmap.match_exhaustive(str(out / "database.db"))
    models = pycolmap.incremental_mapping(str(out / "database.db"), str(images), str(out / SparseModel.MODELS))
    best = max(models.values(), key=lambda r: r.num_reg_images()) if models else None
    return time.perf_counter() - start, best


def recon_run(images: Path, ws: Path, model: str) -> tuple[float, object]:
    import pycolmap

    shutil.rmtree(ws, ignore_errors=True)
    start = time.perf_counter()
    recon.run(REPO / "pipelines" / "sparse.yaml", images=str(images), workspace=str(ws),
              overrides={"ingest.camera_model": model})
    return time.perf_counter() - start, pycolmap.Reconstruction(str(Published(ws).model()))


def _poses(rec) -> dict:
    if rec is None:
        return {}
    return {image.name: (image.cam_from_world().rotation.matrix(), image.cam_from_world().translation)
            for image in rec.images.values() if image.has_pose}


def bench(out: Path) -> list[dict]:
    from recon.logs import quiet_colmap

    quiet_colmap(out / "colmap-log.")
    fisheye, room = scene(out, "fisheye_orbit"), scene(out, "room_walk")
    info = load_scene(fisheye)
    exact = list(fisheye_params(info.width, info.height))
    runs = [
        (fisheye, "COLMAP defaults", "OPENCV_FISHEYE", lambda d: colmap_run(fisheye / "images", d, "OPENCV_FISHEYE")),
        (fisheye, "COLMAP, exact f", "OPENCV_FISHEYE",
         lambda d: colmap_run(fisheye / "images", d, "OPENCV_FISHEYE", exact)),
        (fisheye, "recon", "OPENCV_FISHEYE", lambda d: recon_run(fisheye / "images", d, "OPENCV_FISHEYE")),
        (fisheye, "recon", "SIMPLE_RADIAL", lambda d: recon_run(fisheye / "images", d, "SIMPLE_RADIAL")),
        (room, "COLMAP defaults", "EQUIRECTANGULAR", lambda d: colmap_run(room / "images", d, "EQUIRECTANGULAR")),
        (room, "recon", "auto", lambda d: recon_run(room / "images", d, "auto")),
    ]
    rows = []
    for k, (root, tool, model, run) in enumerate(runs):
        seconds, model_found = run(out / "runs" / f"{root.name}-{k}")
        figures = pose_metrics(_poses(model_found), load_cameras(root))
        rows.append({"dataset": root.name, "tool": tool, "model": model, "seconds": seconds,
                     "registered": figures["registered"], "images": figures["total"],
                     **{key: figures[key] for key in ("auc@1", "auc@3", "auc@5")}})
    return rows


def print_rows(rows: list[dict]) -> None:
    head = f"{'dataset':<15}{'tool':<17}{'camera model':<17}{'seconds':>8}{'reg':>7}{'AUC@1':>7}{'AUC@3':>7}{'AUC@5':>7}"
    print(head)
    print("-" * len(head))
    for r in rows:
        print(f"{r['dataset']:<15}{r['tool']:<17}{r['model']:<17}{r['seconds']:>8.1f}"
              f"{r['registered']:>4}/{r['images']:<2}{r['auc@1']:>7.1f}{r['auc@3']:>7.1f}{r['auc@5']:>7.1f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m recon.wide_bench")
    parser.add_argument("--out", type=Path, default=REPO / "bench_out" / "wide")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    print("\n== fisheye and 360: recon vs COLMAP's defaults with the same camera model ==", flush=True)
    print_rows(bench(args.out))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
