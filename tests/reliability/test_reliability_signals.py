"""SIGTERM stops recon as Ctrl-C does (one line, exit 143, finished work kept), in the main process
and in its workers; log lines with file names that are not UTF-8 are written escaped, never as a
logging traceback. (Ctrl-C and kill -9 inside each stage: test_reliability_runs.py.)"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import signal
import subprocess
import sys
import time

import pytest
from reliability_checks import SPARSE, assert_same_reconstruction, cli, complete_outputs, partial_outputs

from recon.workspace import read_json

TERMINATED = ("recon: terminated (SIGTERM); finished stages and items are kept: run the same command again "
              "to resume")
#: what glog's failure-signal handler (installed by pycolmap) prints
NATIVE_DUMP = ("*** SIGTERM", "*** Aborted at", "stack trace")

#: runs ``recon`` and sends SIGTERM to itself once the stage named in argv[1] has logged "done"
#: (committed and published: the signal comes between two stages)
BETWEEN_STAGES = """
import logging, os, signal, sys
import recon.cli

class AfterStage(logging.Handler):
    def emit(self, record):
        if record.getMessage().startswith(sys.argv[1] + ": done in"):
            os.kill(os.getpid(), signal.SIGTERM)

logging.getLogger("recon").addHandler(AfterStage())
sys.exit(recon.cli.main(sys.argv[2:]))
"""


def assert_terminated_cleanly(proc: subprocess.CompletedProcess) -> None:
    assert proc.returncode == 143, (proc.returncode, proc.stderr[-3000:])
    assert "Traceback" not in proc.stderr and not any(s in proc.stderr for s in NATIVE_DUMP), proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines()[-1] == TERMINATED


def test_sigterm_between_stages_is_one_line_and_keeps_the_finished_stage(copy_workspace, sparse_workspace,
                                                                         small_scene):
    """pycolmap (imported by sfm in the main process) installs glog's SIGTERM handler, which used to
    print a native stack dump and kill the process by the signal."""
    args = ["run", str(SPARSE), "--images", str(small_scene / "images"), "--workspace", str(copy_workspace)]
    proc = subprocess.run([sys.executable, "-c", BETWEEN_STAGES, "sfm", *args, "--force", "sfm"],
                          capture_output=True, text=True, timeout=300)
    assert_terminated_cleanly(proc)
    sfm, = complete_outputs(copy_workspace, "sfm")
    assert partial_outputs(copy_workspace, "sfm") == []
    finished = read_json(sfm / "manifest.json")["finished"]
    again = cli(*args)
    assert again.returncode == 0, again.stderr[-3000:]
    assert again.stdout.startswith("recon: ran nothing (all cached)")  # sfm was kept, export was already there
    assert read_json(sfm / "manifest.json")["finished"] == finished
    assert_same_reconstruction(copy_workspace, sparse_workspace)


@pytest.mark.slow
def test_sigterm_to_the_whole_run_stops_workers_quietly_and_the_rerun_resumes(small_scene, tmp_path):
    """A batch scheduler (``scancel``) or ``kill -- -PGID`` signals every process: the workers (which
    preload pycolmap) end without a native stack dump, the main process says one line, and the
    photos whose features were written are not computed again."""
    ws = tmp_path / "ws"
    args = ["run", str(SPARSE), "--images", str(small_scene / "images"), "--workspace", str(ws),
            "-o", "executor=processes:2", "--until", "features"]
    proc = subprocess.Popen([sys.executable, "-m", "recon.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while len(list(ws.glob(".recon/cache/features/*.partial/features/*.npz"))) < 3:
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read() if proc.poll() else "slow"
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    assert_terminated_cleanly(subprocess.CompletedProcess(proc.args, proc.returncode, out, err))
    kept = len(list(partial_outputs(ws, "features")[0].glob("features/*.npz")))
    assert kept >= 3
    again = cli(*args)
    assert again.returncode == 0, again.stderr[-3000:]
    assert f"features: {kept} of 16 already done" in again.stderr


NAME = os.fsdecode(b"caf\xe9.jpg")  # a photo named in Latin-1: a surrogate in Python's string
LINE = "ingest: caf\\udce9.jpg is not a readable photo; skipped"


def test_file_names_that_are_not_utf8_are_logged_escaped(tmp_path, capfd):
    """A strict stream cannot encode the surrogate: the console and the log file handlers write it
    escaped, and logging prints no traceback of its own."""
    from recon.logs import file_handler, setup_console

    log = logging.getLogger("recon")
    saved = log.handlers[:]
    log.handlers.clear()  # only the two handlers under test (other tests leave their workspace logs)
    setup_console(0)
    log.addHandler(handler := file_handler(tmp_path / "recon.log"))
    strict = io.TextIOWrapper(io.BytesIO(), encoding="utf-8", errors="strict")
    try:
        with contextlib.redirect_stderr(strict):
            log.warning("ingest: %s is not a readable photo; skipped", NAME)
            strict.flush()
    finally:
        handler.close()
        log.handlers[:] = saved
    assert strict.buffer.getvalue().decode() == LINE + "\n"
    assert (tmp_path / "recon.log").read_text().strip() == LINE
    assert "Logging error" not in capfd.readouterr().err


def test_the_workspace_log_of_a_run_escapes_names_that_are_not_utf8(copy_workspace, small_scene, capfd):
    """The same through the log file a run opens in its workspace."""
    import recon

    recon.run(SPARSE, images=str(small_scene / "images"), workspace=str(copy_workspace))  # all cached
    capfd.readouterr()
    logging.getLogger("recon").warning("ingest: %s is not a readable photo; skipped", NAME)
    assert "Logging error" not in capfd.readouterr().err
    assert (copy_workspace / ".recon" / "recon.log").read_text().strip().endswith(LINE)
