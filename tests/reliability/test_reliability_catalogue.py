"""No traceback: every bad input of the catalogue gets exit code 2 and one ``recon: error:`` line
saying what is wrong and what to do. The runs that need real work (a set that cannot be
reconstructed, a full disk) are in the other files of this folder, with the same checks."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image
from reliability_checks import SPARSE

#: runs ``recon.cli.main`` on each case in one interpreter (one start-up for the whole catalogue),
#: capturing file descriptor 2 so that C++ output and tracebacks are caught too
DRIVER = """
import json, os, sys, tempfile
import recon.cli
from recon.workspace import Workspace

cases, result_file = json.loads(sys.argv[1]), sys.argv[2]
results = []
for case in cases:
    with tempfile.TemporaryFile() as err:
        saved = os.dup(2)
        os.dup2(err.fileno(), 2)
        try:
            if case.get("hold"):  # another run holds this workspace
                with Workspace(case["hold"]).locked():
                    rc = recon.cli.main(case["argv"])
            else:
                rc = recon.cli.main(case["argv"])
        except SystemExit as exc:
            rc = exc.code
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
        err.seek(0)
        results.append({"rc": rc, "stderr": err.read().decode(errors="replace")})
with open(result_file, "w") as f:
    json.dump(results, f)
"""


def catalogue(tmp: Path, scene: Path, workspace: Path, photo: np.ndarray) -> list[tuple[dict, str]]:
    """(case, what its error line says) for each bad input."""
    def folder(name: str) -> Path:
        path = tmp / name
        path.mkdir()
        return path

    def config(name: str, text: str) -> Path:
        (tmp / name).write_text(text)
        return tmp / name

    notes = folder("not photos")
    (notes / "readme.txt").write_text("no photo here")
    broken = folder("broken")
    (broken / "cut.jpg").write_bytes(b"\xff\xd8\xff\xe0 truncated")
    (broken / "empty.png").write_bytes(b"")
    one = folder("one photo")
    Image.fromarray(photo).save(one / "a.jpg")
    (tmp / "a file").write_text("not a folder")
    colmap_project = folder("colmap project")  # a user's COLMAP database where recon's would go
    (colmap_project / "database.db").write_bytes(b"the user's database")
    images = scene / "images"
    run = ["run", str(SPARSE), "--images", str(images), "--workspace"]
    ws = str(tmp / "fresh ws")  # (tmp / "ws" is copy_workspace)
    cases = [
        (["run", str(SPARSE), "--images", str(tmp / "absent"), "--workspace", ws], f"images: {tmp / 'absent'} is not a folder"),
        (["run", str(SPARSE), "--images", str(folder("empty")), "--workspace", ws], "holds no JPEG, PNG or TIFF photos"),
        (["run", str(SPARSE), "--images", str(notes), "--workspace", ws], "holds no JPEG, PNG or TIFF photos"),
        (["run", str(SPARSE), "--images", str(broken), "--workspace", ws], "has 0 readable photo(s); the run needs at least 2 (ingest.min_photos)"),
        (["run", str(SPARSE), "--images", str(one), "--workspace", ws], "has 1 readable photo(s); the run needs at least 2 (ingest.min_photos)"),
        (["run", str(tmp / "absent.yaml"), "--workspace", ws], f"{tmp / 'absent.yaml'}: config file not found"),
        (["run", str(config("bad.yaml", "features:\n  upright: [true\n")), "--workspace", ws], "bad.yaml:3:1: invalid YAML"),
        (["run", str(config("list.yaml", "- a\n- b\n")), "--workspace", ws], "the top level must be a mapping"),
        (["run", str(config("number_key.yaml", "1: 2\n")), "--workspace", ws], "1: unknown key; valid keys:"),
        (["run", str(config("typo.yaml", "featurs: {}\n")), "--workspace", ws], "featurs: unknown key; did you mean 'features'?"),
        ([*run, ws, "-o", "features.max_image_size=big"], "features.max_image_size: expected an integer"),
        ([*run, ws, "-o", "features.max_image_size=-5"], "features.max_image_size: must be > 0; got -5"),
        ([*run, ws, "-o", "matching.max_ratio=1.5"], "matching.max_ratio: must be <= 1; got 1.5"),
        ([*run, ws, "-o", "seed=99999999999999999999"], "seed: must be an integer from 0 to 2147483647"),
        (["run", str(config("bomb.yaml", "a: &a [x, x, x, x, x, x, x, x]\n" + "".join(
            f"{b}: &{b} [{', '.join([f'*{a}'] * 8)}]\n" for a, b in zip("abcdefg", "bcdefgh")))),
          "--workspace", ws], "bomb.yaml: expands to more than 1 MB through YAML aliases"),
        ([*run, ws, "-o", "features.type=aliked"], "features.type: 'aliked' needs pycolmap built with ONNX support"),
        ([*run, ws, "-o", "features.max_image_size"], "expected key=value"),
        ([*run, ws, "-o", "executor=gpu"], "executor: 'gpu' is not one of"),
        ([*run, ws, "-o", "stages=[features, mesher]"], "stages: unknown stage 'mesher'"),
        (["run", str(config("video.yaml", "video: absent.mp4\n")), "--workspace", ws], "absent.mp4 is not a file"),
        ([*run, ws, "-o", f"calibrate.images={tmp / 'absent'}"], "calibrate.images:"),
        ([*run, ws, "-o", f"preprocess.mask_dir={tmp / 'absent'}"], "preprocess.mask_dir:"),
        ([*run, str(tmp / "a file" / "ws")], "cannot create the workspace (Not a directory)"),
        ([*run, str(colmap_project)], f"{colmap_project / 'database.db'} exists and recon did not make it"),
        ([*run, ws, "--from", "sfm"], "--from sfm: stage 'ingest' before it has no complete output"),
        ([*run, ws, "--until", "mesher"], "unknown stage 'mesher'"),
        (["run", str(SPARSE)], "workspace: no workspace given"),
        (["status", str(folder("plain"))], "not a recon workspace"),
        (["clean", str(tmp / "plain")], "not a recon workspace"),
        (["eval", str(tmp / "plain"), "--gt", str(scene)], "no sparse model at sparse/0"),
        (["eval", str(workspace), "--gt", str(tmp / "absent")], "--gt"),
        (["view", str(tmp / "plain")], "no report.html"),
        (["config", "show", str(tmp / "absent.yaml")], "config file not found"),
    ]
    found = [({"argv": argv}, says) for argv, says in cases]
    found.append(({"argv": [*run, str(workspace)], "hold": str(workspace)}, "workspace is in use by pid"))
    return found


def test_bad_inputs_get_one_line_and_no_traceback(tmp_path, small_scene, copy_workspace):
    photo = np.asarray(Image.open(small_scene / "images" / "view_000.jpg"))
    state = (copy_workspace / ".recon" / "state.json").read_text()
    cases = catalogue(tmp_path, small_scene, copy_workspace, photo)
    results_file = tmp_path / "results.json"
    subprocess.run([sys.executable, "-c", DRIVER, json.dumps([c for c, _ in cases]), str(results_file)],
                   check=True, timeout=300, cwd=tmp_path)
    results = json.loads(results_file.read_text())
    failures = []
    for (case, says), result in zip(cases, results, strict=True):
        lines = result["stderr"].strip().splitlines()
        ours = [line for line in lines if line.startswith("recon:")]
        ok = (result["rc"] == 2 and "Traceback" not in result["stderr"] and len(ours) == 1
              and ours[0] == lines[-1] and ours[0].startswith("recon: error: ") and says in ours[0])
        if not ok:
            failures.append(f"{' '.join(case['argv'])}: rc={result['rc']}: {result['stderr'][-800:]}")
    assert not failures, "\n".join(failures)
    assert (copy_workspace / ".recon" / "state.json").read_text() == state  # the workspace in use is untouched
