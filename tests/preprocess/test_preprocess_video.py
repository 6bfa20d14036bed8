"""Video input (criterion 5): keyframes of a rendered orbit video skip blurred frames, are spread by
parallax, and reconstruct with every keyframe registered."""

from __future__ import annotations

from pathlib import Path

import av
import cv2
import numpy as np
import pycolmap
import pytest

import recon
from recon.eval.groundtruth import Camera
from recon.eval.poses import pose_metrics
from recon.files import read_json
from recon.synth.cameras import ORBIT_ELEVATION_DEG, ORBIT_RADIUS, intrinsics, look_at
from recon.synth.render import Renderer
from recon.synth.scene import TARGET, build_scene

WIDTH, HEIGHT, FRAMES = 320, 240, 90
BLURRED = {6, 7, 19, 31, 40, 41, 52, 63, 64, 75, 86}
REPO = Path(__file__).resolve().parents[2]
KEYFRAMES = {"min_parallax": 0.025}  # median track motion of 10 px between keyframes: ~6 degrees of orbit


def azimuths() -> np.ndarray:
    """Orbit azimuth of each frame, degrees: 0.5 per frame for the first half, 1.5 after (3x faster)."""
    step = np.where(np.arange(FRAMES) < FRAMES // 2, 0.5, 1.5)
    return np.concatenate([[0.0], np.cumsum(step)[:-1]])


def orbit_camera(azimuth: float) -> Camera:
    a, e = np.radians(azimuth), np.radians(ORBIT_ELEVATION_DEG)
    centre = TARGET + ORBIT_RADIUS * np.array([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)])
    R, t = look_at(centre, TARGET)
    return Camera(intrinsics(WIDTH, HEIGHT), R, t, WIDTH, HEIGHT)


@pytest.fixture(scope="module")
def orbit_video(tmp_path_factory) -> Path:
    """90 frames of the synthetic scene along a quarter orbit, BLURRED frames Gaussian-blurred (sigma 2.5)."""
    renderer = Renderer(build_scene(0))
    path = tmp_path_factory.mktemp("video") / "orbit.mp4"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=30)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.options = {"crf": "18"}
        for i, azimuth in enumerate(azimuths()):
            frame, _, _ = renderer.render(orbit_camera(azimuth))
            if i in BLURRED:
                frame = cv2.GaussianBlur(frame, (0, 0), 2.5)
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def frame_index(name: str) -> int:
    return int(Path(name).stem.rsplit("_", 1)[1])


def check_keyframes(names: list[str]) -> list[int]:
    """The keyframes avoid blurred frames and are spread evenly in azimuth (not in time)."""
    indices = sorted(frame_index(n) for n in names)
    gaps = np.diff(azimuths()[indices])
    uniform = np.linspace(0, FRAMES - 1, len(indices)).round().astype(int)
    uniform_gaps = np.diff(azimuths()[uniform])
    print(f"keyframes {indices}\nazimuth gaps {gaps.tolist()}\nsame count evenly in time: {uniform_gaps.tolist()}")
    assert not set(indices) & BLURRED
    assert len(indices) >= 10
    assert gaps.max() / gaps.min() < 2.0
    assert uniform_gaps.max() / uniform_gaps.min() >= 2.5
    return indices


def test_ingest_takes_keyframes_from_the_video(orbit_video, tmp_path):
    ws = tmp_path / "ws"
    config = {"until": "ingest", "video": str(orbit_video), "ingest": {"keyframes": KEYFRAMES}}
    result = recon.run(config, workspace=str(ws))
    out = ws / ".recon" / "cache" / "ingest" / read_json(ws / ".recon" / "state.json")["ingest"][:16]
    listing = read_json(out / "images.json")
    assert listing["ordered"] is True and result.summaries["ingest"]["ordered"] is True
    assert len(listing["cameras"]) == 1 and listing["cameras"][0]["width"] == WIDTH
    check_keyframes([i["name"] for i in listing["images"]])
    assert sorted(p.name for p in (out / "images").iterdir()) == [i["name"] for i in listing["images"]]
    # the video file is ingest's input: its content is in the key
    again = recon.run(config, workspace=str(ws))
    assert again.ran == []
    other = tmp_path / "orbit.mp4"
    other.write_bytes(orbit_video.read_bytes()[:-1000])  # another file, same name
    rows = {r.name: r for r in recon.api.status({**config, "video": str(other)}, workspace=str(ws))}
    assert rows["ingest"].state == "stale" and rows["ingest"].why == "input files changed"


@pytest.mark.slow
def test_video_pipeline_registers_every_keyframe(orbit_video, tmp_path):
    ws = tmp_path / "ws"
    result = recon.run(REPO / "pipelines" / "video.yaml", workspace=str(ws), video=str(orbit_video),
                       matching={"method": "auto"},  # auto: sequential, since the input is a video
                       overrides={"ingest.keyframes.min_parallax": KEYFRAMES["min_parallax"]})
    assert result.summaries["matching"]["method"] == "sequential"
    rec = pycolmap.Reconstruction(str(ws / "sparse" / "0"))
    ingest = ws / ".recon" / "cache" / "ingest" / read_json(ws / ".recon" / "state.json")["ingest"][:16]
    names = [i["name"] for i in read_json(ingest / "images.json")["images"]]
    check_keyframes(names)
    gt = {n: orbit_camera(azimuths()[frame_index(n)]) for n in names}
    est = {i.name: (i.cam_from_world().rotation.matrix(), i.cam_from_world().translation)
           for i in rec.images.values() if i.has_pose}
    poses = pose_metrics(est, gt)
    print(f"registered {rec.num_reg_images()}/{len(names)} keyframes; AUC@1/5 {poses['auc@1']:.1f}/"
          f"{poses['auc@5']:.1f}")
    assert sorted(est) == sorted(names)
    assert poses["auc@5"] > 80.0
