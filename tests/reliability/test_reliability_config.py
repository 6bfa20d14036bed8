"""Config mistakes: missing paths, an output folder that cannot be written, and properties of the
config loader over random configs. (Unreadable YAML, unknown and mistyped keys, out-of-range values:
tests/spine/test_config.py.)"""

from __future__ import annotations

import dataclasses
import subprocess
import types
import typing
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from reliability_checks import SPARSE, assert_one_line_error, cli

from recon.config import ConfigError, RunOptions
from recon.imaging.ops import OPS
from recon.pipeline import load_config
from recon.stage import REGISTRY

# ---------------------------------------------------------------------------------------------
# Missing paths and unwritable output folders


def test_missing_images_folder_is_named_and_the_workspace_is_untouched(copy_workspace, tmp_path):
    state = (copy_workspace / ".recon" / "state.json").read_text()
    proc = cli("run", SPARSE, "--images", tmp_path / "no such folder", "--workspace", copy_workspace)
    assert_one_line_error(proc, f"images: {tmp_path / 'no such folder'} is not a folder; pass the folder that "
                                "holds the photos")
    assert (copy_workspace / ".recon" / "state.json").read_text() == state
    status = cli("status", copy_workspace)
    assert status.returncode == 0 and all(line.split()[1] == "done" for line in status.stdout.splitlines())


def test_missing_config_file_is_named(tmp_path):
    assert_one_line_error(cli("run", tmp_path / "sparse.yml", "--workspace", tmp_path / "ws"),
                          f"{tmp_path / 'sparse.yml'}: config file not found")
    assert not (tmp_path / "ws").exists()


def test_workspace_that_cannot_be_created_is_named(tmp_path, small_scene):
    (tmp_path / "a file").write_text("not a folder")
    ws = tmp_path / "a file" / "ws"
    assert_one_line_error(cli("run", SPARSE, "--images", small_scene / "images", "--workspace", ws),
                          f"{ws}: cannot create the workspace (Not a directory)")


@pytest.fixture
def read_only(tmp_path):
    """``bind(src) -> path``: a read-only view of folder ``src`` (a bind mount; needs root)."""
    mounts = []

    def bind(src: Path) -> Path:
        dest = tmp_path / f"read-only {len(mounts)}"
        dest.mkdir()
        if subprocess.run(["mount", "--bind", str(src), str(dest)], capture_output=True).returncode:
            pytest.skip("cannot bind-mount here (needs root)")
        mounts.append(dest)
        subprocess.run(["mount", "-o", "remount,bind,ro", str(dest)], check=True)
        return dest

    yield bind
    for dest in mounts:
        subprocess.run(["umount", "-l", str(dest)], check=True)


def test_read_only_workspace_is_refused_and_its_results_stay_readable(copy_workspace, small_scene, read_only):
    """As root, permissions do not stop writes: a read-only mount does. A finished workspace on it
    cannot run again (one line says so) but `recon status` still reads it; a new workspace inside
    it cannot be created."""
    ws = read_only(copy_workspace)
    images = small_scene / "images"
    assert_one_line_error(cli("run", SPARSE, "--images", images, "--workspace", ws),
                          f"{ws}: workspace folder is not writable; choose another --workspace or fix its permissions")
    assert_one_line_error(cli("run", SPARSE, "--images", images, "--workspace", ws / "new"),
                          f"{ws / 'new'}: cannot create the workspace (Read-only file system)")
    status = cli("status", ws)
    assert status.returncode == 0 and all(line.split()[1] == "done" for line in status.stdout.splitlines())


# ---------------------------------------------------------------------------------------------
# Properties of the config loader

#: options that a type alone does not describe: values that are valid for them
SPECIAL = {
    ("", "executor"): st.sampled_from(["local", "serial", "processes:2", "dask-local:1", "dask://host:8786"]),
    ("", "stages"): st.lists(st.sampled_from(list(REGISTRY)), unique=True, max_size=4),
    ("", "until"): st.sampled_from(list(REGISTRY)),
    ("", "video"): st.none(),  # images or video, not both: images is drawn
    ("features", "type"): st.sampled_from(["sift", "SIFT"]),
    ("preprocess", "ops"): st.lists(st.sampled_from(list(OPS)).map(lambda name: {"op": name}), max_size=2),
}
TEXT = st.text(st.characters(codec="utf-8", exclude_categories=("Cc", "Cs")), max_size=12)


def bounded(field: dataclasses.Field, lo: float, hi: float) -> tuple[float, float, bool, bool]:
    meta = field.metadata
    low = next((meta[k] for k in ("ge", "gt") if meta.get(k) is not None), lo)
    high = next((meta[k] for k in ("le", "lt") if meta.get(k) is not None), hi)
    return low, high, meta.get("gt") is not None, meta.get("lt") is not None


def values(tp, field: dataclasses.Field | None, path: tuple[str, str]) -> st.SearchStrategy:
    """Valid values of an option of type ``tp`` (its bounds from ``field``)."""
    if path in SPECIAL:
        return SPECIAL[path]
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        return st.one_of(*[st.none() if a is type(None) else values(a, field, path) for a in args])
    if origin is typing.Literal:
        return st.sampled_from(args)
    if origin is list:
        return st.lists(values(args[0], None, path), max_size=3)
    if dataclasses.is_dataclass(tp):
        return sections(tp, path[1])
    if tp is bool:
        return st.booleans()
    if tp is int:
        low, high, open_low, open_high = bounded(field, -10**6, 10**6) if field else (-10**6, 10**6, False, False)
        return st.integers(int(low) + open_low, int(high) - open_high)
    if tp is float:
        low, high, open_low, open_high = bounded(field, -1e6, 1e6) if field else (-1e6, 1e6, False, False)
        return st.floats(low, high, exclude_min=open_low, exclude_max=open_high, allow_nan=False)
    if tp is str:
        return TEXT
    raise AssertionError(f"no strategy for {tp} at {path}")


def sections(cls: type, name: str) -> st.SearchStrategy:
    """Mappings of some of the options of dataclass ``cls`` to valid values."""
    hints = typing.get_type_hints(cls)
    fields = {f.name: values(hints[f.name], f, (name, f.name)) for f in dataclasses.fields(cls)}
    return st.fixed_dictionaries({}, optional=fields)


CONFIGS = st.tuples(sections(RunOptions, ""), st.fixed_dictionaries(
    {}, optional={name: sections(stage.Config, name) for name, stage in REGISTRY.items()})).map(
    lambda parts: {**parts[0], **parts[1]})


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(CONFIGS)
def test_valid_configs_load_and_round_trip(data):
    """Any mapping of known keys to valid values loads, holds those values, and the resolved config
    written as YAML and read back is the same config."""
    cfg = load_config(data)
    full = cfg.as_dict()
    for key, value in data.items():
        if key == "preprocess":  # ops are spelled out with every option
            value = {k: v for k, v in value.items() if k != "ops"}
        assert holds(full[key], value), key
    assert load_config(yaml.safe_load(yaml.safe_dump(full, allow_unicode=True))).as_dict() == full


def holds(built, given_value) -> bool:
    """``built`` has every value of ``given_value`` (nested mappings: the keys given)."""
    if isinstance(given_value, dict):
        return all(holds(built[k], v) for k, v in given_value.items())
    if isinstance(given_value, list):  # e.g. sfm.scale_bars: each item a mapping of some of its options
        return len(built) == len(given_value) and all(map(holds, built, given_value))
    return built == given_value


KEYS = st.one_of(TEXT.filter(bool), st.integers(), st.booleans(), st.none(), st.floats(allow_nan=False))


@settings(max_examples=150, deadline=None)
@given(st.data())
def test_unknown_keys_are_errors_naming_the_key(data):
    where = data.draw(st.sampled_from(["", *REGISTRY, "ingest.keyframes", "preprocess.ops[0]"]))
    if where == "":
        known = {f.name for f in dataclasses.fields(RunOptions)} | set(REGISTRY)
    elif where == "ingest.keyframes":
        known = {f.name for f in dataclasses.fields(type(load_config({}).stages["ingest"].keyframes))}
    elif where == "preprocess.ops[0]":
        known = {"op", *(f.name for f in dataclasses.fields(OPS["clahe"].Options))}
    else:
        known = {f.name for f in dataclasses.fields(REGISTRY[where].Config)}
    key = data.draw(KEYS.filter(lambda k: str(k) not in known and k not in known))
    config: dict = {key: 1}
    if where == "ingest.keyframes":
        config = {"ingest": {"keyframes": config}}
    elif where == "preprocess.ops[0]":
        config = {"preprocess": {"ops": [{"op": "clahe", **config}]}}
    elif where:
        config = {where: config}
    with pytest.raises(ConfigError) as info:
        load_config(config)
    full = f"{where}.{key}" if where else str(key)
    assert str(info.value).startswith(f"{full}: unknown key; "), str(info.value)
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------------------------
# Values the YAML reader or a C library would mishandle (issue 13)


@pytest.mark.parametrize(("override", "says"), [
    ("seed=99999999999999999999", "seed: must be an integer from 0 to 2147483647; got 99999999999999999999"),
    ("seed=2147483648", "seed: must be an integer from 0 to 2147483647; got 2147483648"),
    ("features.max_image_size=-99999999999", "features.max_image_size: must be an integer from 1 to 2147483647"),
    ("mvs.seed=4294967296", "mvs.seed: must be an integer from 0 to 2147483647"),
])
def test_integers_beyond_a_c_int_are_refused_naming_the_key_and_range(override, says):
    with pytest.raises(ConfigError) as info:
        load_config({}, [override])
    assert str(info.value).startswith(says) and "\n" not in str(info.value)


def test_the_largest_c_int_seed_is_accepted_and_reaches_colmap():
    """The bound is what pycolmap's RANSAC seed takes: the largest accepted value works there."""
    import pycolmap

    seed = load_config({}, ["seed=2147483647"]).run.seed
    pycolmap.RANSACOptions().random_seed = seed
    with pytest.raises(TypeError):
        pycolmap.RANSACOptions().random_seed = seed + 1


def test_exponent_without_a_dot_is_a_number_in_files_and_overrides(tmp_path):
    """YAML 1.1 reads ``5e-3`` as a string; for a number option it is the number."""
    (tmp_path / "c.yaml").write_text("matching:\n  max_error: 5e-1\nfusion:\n  max_depth_error: 5E-3\n")
    cfg = load_config(tmp_path / "c.yaml")
    assert cfg.stages["matching"].max_error == 0.5 and cfg.stages["fusion"].max_depth_error == 0.005
    assert load_config({}, ["matching.max_error=5e-3"]).stages["matching"].max_error == 0.005
    assert load_config({}, ["matching.max_error=+2.5e+1"]).stages["matching"].max_error == 25.0
    for bad in ("matching.max_error=5e", "matching.max_error=nan", "features.max_image_size=1e3"):
        with pytest.raises(ConfigError, match=r"^(matching\.max_error: expected a number|"
                                              r"features\.max_image_size: expected an integer)"):
            load_config({}, [bad])


def billion_laughs(levels: int = 7) -> str:
    """A YAML file of a few hundred bytes that expands to 10**levels strings (30 MB at 7 levels; small
    enough that the unbounded loader of old fails the test rather than the machine)."""
    lines = ["a0: &a0 [lol, lol, lol, lol, lol, lol, lol, lol, lol, lol]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, levels)]
    return "\n".join([*lines, f"features: {{upright: *a{levels - 1}}}", ""])


@pytest.mark.parametrize("text", [billion_laughs(), "stages: &loop [*loop]\n"])
def test_alias_bomb_is_refused_naming_the_file(tmp_path, text):
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    assert len(text) < 1000
    with pytest.raises(ConfigError) as info:
        load_config(path, ["seed=1"])  # an override copies the whole config: the old blow-up
    assert str(info.value) == (f"{path}: expands to more than 1 MB through YAML aliases (or an alias refers "
                               "to itself); write it out without them")


def test_alias_bomb_in_an_override_is_refused():
    with pytest.raises(ConfigError, match=r"^override stages: expands to more than 1 MB"):
        load_config({}, ["stages=&a [*a, *a, *a]"])


def test_aliases_within_the_bound_still_work(tmp_path):
    (tmp_path / "c.yaml").write_text("features: {max_image_size: &size 1200}\nundistort: {max_image_size: *size}\n")
    cfg = load_config(tmp_path / "c.yaml")
    assert cfg.stages["features"].max_image_size == cfg.stages["undistort"].max_image_size == 1200
