"""The report's "Scale and position" section, from georeference.json written for the small scene's model
placed on GCPs and GPS, or scaled by a scale bar: the residual tables and the map."""

from __future__ import annotations

import json
import re

import numpy as np
import pycolmap
from control_scene import ORIGIN, marked_points, true_enu, write_gcp_list

from recon.geometry.gcp import read_gcp_list
from recon.geometry.gps import wgs84_from_enu
from recon.report import Sources, build_report
from recon.sparse.control import BarEnd, ScaleBar
from recon.sparse.georeference import place
from recon.synth import load_scene


def _page(model, result: dict, tmp_path) -> str:
    folder = tmp_path / "model"
    folder.mkdir()
    model.write(str(folder))
    (tmp_path / "georeference.json").write_text(json.dumps(result))
    return build_report(Sources(model=folder, georeference=tmp_path / "georeference.json"), title="t").html


def _section(page: str) -> str:
    return re.search(r'<section id="georeference">(.*?)</section>', page, re.S).group(1)


def test_gcps_and_gps_section_with_map(small_scene, sparse_workspace, tmp_path):
    model = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    truth, rng = true_enu(), np.random.default_rng(0)
    gps = {}
    for name, cam in load_scene(small_scene).cameras().items():
        lat, lon, alt = wgs84_from_enu(truth.apply(cam.center) + rng.normal(0, 2.0, 3), ORIGIN)[0]
        gps[name] = {"lat": lat, "lon": lon, "alt": alt, "dop": None, "horizontal_error": 2.0}
    gps["view_003.jpg"]["lat"] += 0.001  # 111 m north: an outlier
    write_gcp_list(tmp_path / "gcp_list.txt", marked_points(small_scene, 4, noise_px=0.3, seed=3, spread=1.0))
    result = place([model], gps, gcps=read_gcp_list(tmp_path / "gcp_list.txt"))
    section = _section(_page(model, result, tmp_path))
    assert 'data-plot="enu-map"' in section
    assert all(f"<td>gcp_{k}</td>" in section for k in range(4))
    assert "view_003.jpg</td>" in section and "no: outlier" in section
    assert "<b>GCP</b><span>scale from</span>" in section and "GCP leave-one-out check RMS" in section


def test_scale_bar_section_without_map(small_scene, sparse_workspace, tmp_path):
    model = pycolmap.Reconstruction(str(sparse_workspace / "sparse" / "0"))
    a, b = marked_points(small_scene, 2, noise_px=0.3, seed=1, spread=1.5)
    bar = ScaleBar(length=2.5, a=[BarEnd(n, *xy) for n, xy in a.pixels.items()],
                   b=[BarEnd(n, *xy) for n, xy in b.pixels.items()])
    result = place([model], None, scale_bars=[bar])
    section = _section(_page(model, result, tmp_path))
    assert 'id="scale-bars"' in section and "<td class=num>2.5</td>" in section
    assert "<b>scale bar</b><span>scale from</span>" in section and "enu-map" not in section
