"""Config validation: every mistake is one clear message naming the key."""

from __future__ import annotations

import subprocess
import sys

import pytest

from recon.config import ConfigError
from recon.pipeline import load_config


def error_of(data, overrides=None) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(data, overrides)
    return str(info.value)


def test_defaults_fill_an_empty_config():
    cfg = load_config({})
    assert cfg.stages["features"].max_image_size == 1600
    assert cfg.stages["matching"].method == "auto"
    assert cfg.run.executor == "local"


def test_unknown_key_names_full_path_and_closest_key():
    msg = error_of({"features": {"max_image_sise": 1000}})
    assert msg == "features.max_image_sise: unknown key; did you mean 'max_image_size'?"


def test_unknown_section_suggests_stage():
    msg = error_of({"featurs": {}})
    assert msg.startswith("featurs: unknown key; did you mean 'features'?")


def test_wrong_type_names_key_and_expected_type():
    assert error_of({"features": {"max_image_size": "big"}}) == \
        "features.max_image_size: expected an integer, got a string 'big'"
    assert "sfm.refine_focal_length: expected true or false" in error_of({"sfm": {"refine_focal_length": 3}})
    assert "matching.method: must be one of auto, exhaustive" in error_of({"matching": {"method": "fast"}})


def test_out_of_range_values():
    assert error_of({"features": {"max_image_size": -5}}) == "features.max_image_size: must be > 0; got -5"
    assert error_of({"matching": {"max_ratio": 1.5}}) == "matching.max_ratio: must be <= 1; got 1.5"


@pytest.mark.parametrize("name", ["aliked", "ALIKED_N16ROT", "superpoint"])
def test_onnx_features_refused_before_pycolmap(name):
    msg = error_of({"features": {"type": name}})
    assert msg.startswith(f"features.type: '{name}' needs pycolmap built with ONNX support")
    assert "aborts the whole process" in msg


def test_overrides_are_parsed_as_yaml():
    cfg = load_config({"features": {"max_image_size": 3000}},
                      ["features.max_image_size=1000", "matching.cross_check=false", "sfm.mapper=global"])
    assert cfg.stages["features"].max_image_size == 1000
    assert cfg.stages["matching"].cross_check is False
    assert cfg.stages["sfm"].mapper == "global"
    assert "expected key=value" in error_of({}, ["features.max_image_size"])


def test_yaml_syntax_error_names_line_and_column(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("features:\n  max_image_size: 1600\n  upright: [true\n")
    msg = error_of(path)
    assert msg.startswith(f"{path}:4:1: invalid YAML") or msg.startswith(f"{path}:3:")


def test_unknown_stage_in_stages_list():
    assert "stages: unknown stage 'mesher'" in error_of({"stages": ["features", "mesher"]})


def test_bad_executor():
    assert "executor: 'gpu' is not one of" in error_of({"executor": "gpu"})


def test_cli_prints_one_line_error_without_traceback(tmp_path):
    cfg = tmp_path / "c.yaml"
    cfg.write_text("features:\n  type: aliked\n")
    proc = subprocess.run([sys.executable, "-m", "recon.cli", "run", str(cfg), "--workspace", str(tmp_path / "w")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines()[-1].startswith("recon: error: features.type: 'aliked'")


def test_config_show_prints_defaults_with_docs(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "recon.cli", "config", "show", "-o", "features.upright=true"],
                          capture_output=True, text=True, check=True)
    assert "  upright: true  # skip orientation estimation" in proc.stdout
    assert "  max_image_size: 1600  # longest image side" in proc.stdout
