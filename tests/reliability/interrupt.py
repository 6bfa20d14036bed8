"""Run ``recon`` with a signal sent at a chosen point inside a stage (used by the interrupt tests).

    python interrupt.py STAGE SIGNAL RECON-ARGS...

SIGINT goes to the whole process group, as Ctrl-C in a terminal reaches recon and its worker
processes (start this script in a new session); any other signal goes to recon's main process
alone, as the OOM killer or ``kill -9`` would. Each point lies inside the stage, after some of its
work is written and before it is committed.
"""

from __future__ import annotations

import os
import signal
import sys

import recon.cli
import recon.sparse.mapping
import recon.stage
import recon.stages.export
import recon.stages.ingest


def fire(name: str) -> None:
    sig = getattr(signal, name)
    if sig == signal.SIGINT:
        os.killpg(os.getpgrp(), sig)
    else:
        os.kill(os.getpid(), sig)


def after_call(owner, attr: str, signal_name: str, calls: int = 1, desc: str | None = None) -> None:
    """Send the signal when ``owner.attr`` returns for the ``calls``-th time (counting only the
    calls on a Progress whose ``desc`` is ``desc``, when given)."""
    original = getattr(owner, attr)
    count = [0]

    def wrapper(*args, **kwargs):
        result = original(*args, **kwargs)
        if desc is None or args[0].desc == desc:
            count[0] += 1
            if count[0] == calls:
                fire(signal_name)
        return result

    setattr(owner, attr, wrapper)


#: stage -> where its signal goes off
POINTS = {
    "ingest": (recon.stages.ingest, "_place_photos", {}),  # photos linked, images.json not written
    "features": (recon.stage.Progress, "advance", {"calls": 4, "desc": "features"}),  # 4 photos done
    "matching": (recon.stage.Progress, "advance", {"calls": 2, "desc": "matching pairs"}),  # 2 chunks done
    "sfm": (recon.sparse.mapping, "reconstruct", {}),  # models built, nothing written
    "export": (recon.stages.export, "write_points_ply", {}),  # text model and points.ply written
}


if __name__ == "__main__":
    stage, signal_name, *argv = sys.argv[1:]
    owner, attr, kwargs = POINTS[stage]
    after_call(owner, attr, signal_name, **kwargs)
    sys.exit(recon.cli.main(argv))
