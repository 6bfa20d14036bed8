"""Resolve which stages run, check the cache, run them.

The cache key of a stage is the SHA-256 of canonical JSON holding its name and version, its config,
the keys of the stages it reads from, the run's seed where the stage samples, and (ingest) the
content hashes of the input files. A stage whose key is complete on disk is skipped; change one
option and exactly that stage and the stages after it run again (docs/ARCHITECTURE.md, "The cache").
A complete output is reused only after its files are checked against its manifest
(:meth:`Workspace.verify`); a run never starts while a path it would publish holds a file of the
user's (:meth:`Workspace.clashes`).
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import logging
import platform
import shutil
import stat
import time
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from recon import stages as _stages  # noqa: F401  (registers every stage)
from recon.config import ConfigError, RunOptions, apply_overrides, build, read_yaml, to_dict
from recon.executor import Executor, check_spec
from recon.logs import file_handler, native_stderr_to
from recon.options import output_options
from recon.stage import REGISTRY, Stage, StageContext, StageError, resolve_path
from recon.workspace import HashCache, Workspace, WorkspaceError

log = logging.getLogger("recon")


@dataclass
class RunConfig:
    """A validated run: the run's own options and one config per stage."""

    run: RunOptions
    stages: dict[str, Any]
    base: Path = field(default=Path("."))  # folder that relative paths are resolved against

    @property
    def images(self) -> Path | None:
        return resolve_path(self.base, self.run.images) if self.run.images else None

    @property
    def video(self) -> Path | None:
        return resolve_path(self.base, self.run.video) if self.run.video else None

    @property
    def workspace(self) -> Path:
        if not self.run.workspace:
            raise ConfigError("workspace: no workspace given; set `workspace:` in the config or pass --workspace")
        return resolve_path(self.base, self.run.workspace)

    def as_dict(self) -> dict:
        data = to_dict(self.run)
        data.update({name: to_dict(cfg) for name, cfg in self.stages.items()})
        return data


def load_config(source: str | Path | dict | None = None, overrides: list[str] | dict | None = None) -> RunConfig:
    """Read a YAML file (or take a dict), apply overrides, validate everything."""
    if isinstance(source, dict):
        data, base = source, Path.cwd()
    elif source is None:
        data, base = {}, Path.cwd()
    else:
        path = Path(source)
        data, base = read_yaml(path), path.absolute().parent
    data = apply_overrides(data, overrides or [])
    run_keys = {f.name for f in dataclasses.fields(RunOptions)}
    run = build(RunOptions, {k: v for k, v in data.items() if k in run_keys})
    sections = {}
    for key, value in data.items():
        if key in run_keys:
            continue
        if key not in REGISTRY:
            from recon.config import _unknown_key_message

            raise ConfigError(_unknown_key_message(str(key), str(key), sorted(run_keys | set(REGISTRY))))
        sections[key] = value
    stage_cfgs = {name: build(stage.Config, sections.get(name), name) for name, stage in REGISTRY.items()}
    for name in [*run.stages, run.until]:
        if name not in REGISTRY:
            raise ConfigError(f"stages: unknown stage '{name}'; stages are {', '.join(REGISTRY)}")
    check_spec(run.executor)
    return RunConfig(run, stage_cfgs, base)


# ---------------------------------------------------------------------------------------------
# Planning


def selected_stages(cfg: RunConfig) -> list[str]:
    """Stages of this run in pipeline order: the listed ones (or all up to `until`) and what they need."""
    order = list(REGISTRY)
    wanted = set(cfg.run.stages) if cfg.run.stages else set(order[: order.index(cfg.run.until) + 1])
    stack = list(wanted)
    while stack:
        for dep in REGISTRY[stack.pop()].needs:
            if dep not in wanted:
                wanted.add(dep)
                stack.append(dep)
    return [name for name in order if name in wanted]


@dataclass
class Plan:
    """The key and key material of each stage of a run."""

    order: list[str]
    keys: dict[str, str]
    material: dict[str, dict]


def plan(cfg: RunConfig, ws: Workspace) -> Plan:
    hashes = HashCache(ws)
    keys: dict[str, str] = {}
    material: dict[str, dict] = {}
    order = selected_stages(cfg)
    for name in order:
        stage = REGISTRY[name]
        probe = StageContext(name=name, out=Path(), workspace=ws, images=cfg.images, seed=cfg.run.seed,
                             executor=None, base=cfg.base, hashes=hashes, video=cfg.video,
                             upstream={dep: ws.output_dir(dep, keys[dep]) for dep in stage.upstream if dep in keys})
        mat = {
            "stage": name,
            "version": stage.version,
            "config": to_dict(output_options(cfg.stages[name])),
            "upstream": {dep: keys[dep] for dep in stage.upstream if dep in keys},
            "seed": cfg.run.seed if stage.uses_seed else None,
            "fingerprint": stage.fingerprint(probe, cfg.stages[name]),
        }
        material[name] = mat
        keys[name] = hashlib.sha256(json.dumps(mat, sort_keys=True, default=str).encode()).hexdigest()
    if ws.meta.is_dir():
        hashes.save()
    return Plan(order, keys, material)


# ---------------------------------------------------------------------------------------------
# Running


@dataclass
class RunResult:
    workspace: Path
    ran: list[str]
    cached: list[str]
    seconds: dict[str, float]
    summaries: dict[str, dict]


def run(cfg: RunConfig, *, from_stage: str | None = None, until: str | None = None,
        force: list[str] | tuple[str, ...] = (), verify: bool = False) -> RunResult:
    """Run the pipeline: skip what is cached (after checking its files; every byte with ``verify``),
    run the rest in order, publish outputs."""
    ws = Workspace(cfg.workspace)
    for name in [from_stage, until, *force]:
        if name is not None and name not in REGISTRY:
            raise ConfigError(f"unknown stage '{name}'; stages are {', '.join(REGISTRY)}")
    with ws.locked():
        _setup_log_file(ws)
        order = selected_stages(cfg)
        if until is not None:
            if until not in order:
                raise ConfigError(f"--until {until}: stage is not part of this run ({', '.join(order)})")
            order = order[: order.index(until) + 1]
        if from_stage is not None and from_stage not in order:
            raise ConfigError(f"--from {from_stage}: stage is not part of this run ({', '.join(order)})")
        keep = _check_clashes(cfg, ws, order)
        p = plan(cfg, ws)
        ws.save_config(str(cfg.base), cfg.as_dict())  # before any stage: a killed run can be shown by status
        before = set(order[: order.index(from_stage)]) if from_stage else set()
        forced: set[str] = set()
        for name in force:
            if name in order:
                forced.update(order[order.index(name):])
        executor = Executor(cfg.run.executor)
        result = RunResult(ws.root, [], [], {}, {})
        outputs: dict[str, Path] = {}
        try:
            for name in order:
                key = p.keys[name]
                if ws.is_complete(name, key) and name not in forced:
                    damage = ws.verify(name, key, full=verify)
                    if damage is None:
                        outputs[name] = ws.output_dir(name, key)
                        result.cached.append(name)
                        _publish(ws, name, outputs[name], keep)
                        ws.set_state(name, key)
                        log.debug("%s: cached (%s)", name, key[:16])
                        continue
                    log.warning("%s: cached output is damaged (%s); running it again", name, damage)
                if name in before:
                    raise ConfigError(f"--from {from_stage}: stage '{name}' before it has no complete "
                                      "output for this config; run without --from first")
                try:
                    _unpublish_downstream(ws, name)
                    outputs[name] = _run_stage(cfg, ws, name, key, p.material[name], outputs, executor, result,
                                               keep, reuse=name not in forced)
                except (ConfigError, StageError):
                    raise
                except Exception as exc:
                    if not _out_of_space(ws, exc):
                        raise
                    log.debug("%s: failed on a full disk", name, exc_info=True)
                    done = [n for n in order if n in outputs]
                    raise WorkspaceError(
                        f"{name}: the disk holding {ws.root} is full ({shutil.disk_usage(ws.root).free / 1e6:.1f} MB "
                        f"free); completed stages are kept{f' (last: {done[-1]})' if done else ''}: free some "
                        "space and run the same command again to resume") from exc
        except BaseException:  # stopped (Ctrl-C, SIGTERM) or failed: items in flight are redone next time
            executor.shutdown(abandon=True)
            raise
        executor.shutdown()
        return result


def _run_stage(cfg: RunConfig, ws: Workspace, name: str, key: str, material: dict,
               outputs: dict[str, Path], executor: Executor, result: RunResult, keep: set[str],
               reuse: bool = True) -> Path:
    stage = REGISTRY[name]
    out = ws.begin(name, key)
    ctx = StageContext(name=name, out=out, workspace=ws, images=cfg.images, seed=cfg.run.seed,
                       executor=executor, base=cfg.base, hashes=HashCache(ws), video=cfg.video,
                       upstream={d: outputs[d] for d in stage.upstream if d in outputs},
                       settings=cfg.as_dict(), reuse=reuse)
    log.info("%s: running", name)
    start = time.time()
    with native_stderr_to(ws.meta / "logs" / "native.log"):
        summary = stage.run(ctx, cfg.stages[name]) or {}
    seconds = time.time() - start
    missing = stage.produces(out).missing()
    if missing:
        raise RuntimeError(f"{name}: finished without writing {', '.join(missing)}, which its product "
                           f"{stage.produces.__name__} declares")
    manifest = {
        "stage": name,
        "version": stage.version,
        "key": key,
        "config": material["config"],
        "upstream": material["upstream"],
        "seed": material["seed"],
        "fingerprint": material["fingerprint"],
        "started": start,
        "finished": time.time(),
        "seconds": round(seconds, 3),
        "summary": summary,
        "versions": library_versions(),
    }
    final = ws.commit(name, key, manifest)
    ws.set_state(name, key)
    _publish(ws, name, final, keep)
    log.info("%s: done in %.1f s%s", name, seconds, _summary_text(summary))
    result.ran.append(name)
    result.seconds[name] = seconds
    result.summaries[name] = summary
    return final


#: less free space than this after a failure means the disk is full: COLMAP's SQLite and model
#: writers report a full disk vaguely ("No registered database factory succeeded") or not at all
NEAR_FULL = 16 << 20


def _out_of_space(ws: Workspace, exc: BaseException) -> bool:
    """Whether ``exc`` came from a full disk: an ENOSPC/EDQUOT/EFBIG error in its chain, or almost no space left."""
    cause: BaseException | None = exc
    while cause is not None:
        if isinstance(cause, OSError) and cause.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
            return True
        cause = cause.__cause__ or cause.__context__
    try:
        return shutil.disk_usage(ws.root).free < NEAR_FULL
    except OSError:
        return False


def _unpublish_downstream(ws: Workspace, name: str) -> None:
    """Remove the workspace links of every stage that reads (directly or not) from ``name``: about to
    change, ``name`` would leave them showing outputs made from its old output. They come back when
    those stages run, or are found cached, for the new one."""
    affected = {name}
    for stage_name, stage in REGISTRY.items():
        if affected & set(stage.upstream):
            affected.add(stage_name)
            if stage_name != name:
                for link in stage.publish.values():
                    ws.unpublish(link)


def _check_clashes(cfg: RunConfig, ws: Workspace, order: list[str]) -> set[str]:
    """Stop before any work if a path this run would publish holds something recon did not make.
    Returns the links not to publish: the photo folder itself (COLMAP's layout: photos in
    ``proj/images``, workspace ``proj``), which already shows what that link would."""
    links = [link for name in order for link in REGISTRY[name].publish.values()]
    keep = [p for p in (cfg.images,) if p is not None]
    clash, kept = ws.clashes(links, keep)
    if clash:
        more = f" (and {len(clash) - 1} more: {', '.join(p.name for p in clash[1:])})" if len(clash) > 1 else ""
        raise WorkspaceError(f"{clash[0]} exists and recon did not make it{more}; recon never replaces files "
                             "it did not write: choose another --workspace, or move it out of the workspace")
    for path in kept:
        log.info("%s is the photo folder: left as it is (no link published there)", path)
    return {path.relative_to(ws.root).as_posix() for path in kept}


def _publish(ws: Workspace, name: str, out: Path, keep: set[str]) -> None:
    for rel, link in REGISTRY[name].publish.items():
        if (out / rel).exists() and link not in keep:
            ws.publish(out / rel, link)


def _summary_text(summary: dict) -> str:
    parts = [f"{k}={v}" for k, v in summary.items() if isinstance(v, (int, float, str)) and len(str(v)) < 40]
    return f" ({', '.join(parts)})" if parts else ""


def _setup_log_file(ws: Workspace) -> None:
    path = ws.meta / "recon.log"
    root = logging.getLogger("recon")
    for handler in root.handlers:
        if isinstance(handler, logging.FileHandler) and Path(handler.baseFilename) == path:
            return
    for handler in [h for h in root.handlers if isinstance(h, logging.FileHandler)]:
        root.removeHandler(handler)
        handler.close()
    handler = file_handler(path)
    handler.setLevel(logging.DEBUG)
    handler.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    root.addHandler(handler)
    root.setLevel(logging.DEBUG)


def library_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for dist in ("recon", "pycolmap", "numpy", "opencv-python-headless", "open3d", "numba", "trimesh"):
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return versions


# ---------------------------------------------------------------------------------------------
# Status and cleaning


@dataclass
class StageStatus:
    name: str
    state: str  # done | stale | missing
    why: str = ""
    key: str = ""
    reuse: str = ""  # a stale or missing stage: what a run would reuse of earlier runs' per-item results


def status(cfg: RunConfig, verify: bool = False) -> list[StageStatus]:
    """Per stage: done, stale (and why: an option, an input, or a damaged output), or missing."""
    ws = Workspace(cfg.workspace)
    if not ws.meta.is_dir():
        return [StageStatus(n, "missing", "no workspace yet") for n in selected_stages(cfg)]
    p = plan(cfg, ws)
    state = ws.state()
    rows = []
    for name in p.order:
        key = p.keys[name]
        if ws.is_complete(name, key):
            damage = ws.verify(name, key, full=verify)
            rows.append(StageStatus(name, "stale", damage, key) if damage else StageStatus(name, "done", "", key))
            continue
        previous = ws.manifest(name, state[name]) if name in state else None
        if previous is None:
            runs = ws.manifests(name)
            previous = runs[-1] if runs else None
        reuse = _reusable(cfg, ws, p, name)
        if previous is None:
            rows.append(StageStatus(name, "missing", "never run", key, reuse))
        else:
            rows.append(StageStatus(name, "stale", _why_stale(previous, p.material[name]), key, reuse))
    return rows


def _reusable(cfg: RunConfig, ws: Workspace, p: Plan, name: str) -> str:
    """What a run of stage ``name`` would reuse (:meth:`Stage.reusable`), when the outputs it reads
    are complete; else which stage must run first for that to be known."""
    stage = REGISTRY[name]
    upstream = [d for d in stage.upstream if d in p.keys]
    waiting = next((d for d in upstream if not ws.is_complete(d, p.keys[d])), None)
    if waiting is not None:
        return f"reuse known once {waiting} has run" if type(stage).reusable is not Stage.reusable else ""
    ctx = StageContext(name=name, out=Path(), workspace=ws, images=cfg.images, seed=cfg.run.seed, executor=None,
                       base=cfg.base, hashes=HashCache(ws), video=cfg.video,
                       upstream={d: ws.output_dir(d, p.keys[d]) for d in upstream})
    return stage.reusable(ctx, cfg.stages[name]) or ""


def _why_stale(previous: dict, now: dict) -> str:
    if previous.get("version") != now["version"]:
        return f"stage version {previous.get('version')} -> {now['version']}"
    changes = _diff(previous.get("config", {}), now["config"], now["stage"])
    if changes:
        return "; ".join(changes[:3]) + (" ..." if len(changes) > 3 else "")
    ups = [d for d, k in now["upstream"].items() if previous.get("upstream", {}).get(d) != k]
    if ups:
        return f"upstream changed: {', '.join(ups)}"
    if previous.get("seed") != now["seed"]:
        return f"seed {previous.get('seed')} -> {now['seed']}"
    if previous.get("fingerprint") != now["fingerprint"]:
        return "input files changed"
    return "output missing"


def _diff(old: Any, new: Any, path: str) -> list[str]:
    if isinstance(old, dict) and isinstance(new, dict):
        out = []
        for k in sorted(set(old) | set(new)):
            out += _diff(old.get(k), new.get(k), f"{path}.{k}")
        return out
    return [] if old == new else [f"{path}: {old!r} -> {new!r}"]


def _unshared_bytes(files) -> int:
    """Bytes that deleting ``files`` frees: a file hard-linked elsewhere (an item of :mod:`recon.items`
    and a stage output are one file) frees nothing until its last name goes."""
    return sum(st.st_size for st in (f.lstat() for f in files) if stat.S_ISREG(st.st_mode) and st.st_nlink == 1)


def clean(cfg: RunConfig | None, workspace: Path, everything: bool = False) -> tuple[int, int]:
    """Remove cached outputs the current config does not use (or all of them). Returns (folders, bytes)."""
    ws = Workspace(workspace)
    if not ws.meta.is_dir():
        raise WorkspaceError(f"{workspace}: not a recon workspace (no {ws.meta.name}/ folder)")
    with ws.locked():
        keep = set()
        if cfg is not None and not everything:
            p = plan(cfg, ws)
            keep = {ws.output_dir(n, k) for n, k in p.keys.items()}
        elif not everything:
            keep = {ws.output_dir(n, k) for n, k in ws.state().items()}
        removed = freed = 0
        for stage_dir in (ws.meta / "cache").glob("*"):
            for out in stage_dir.iterdir():
                if out in keep:
                    continue
                freed += _unshared_bytes(out.rglob("*"))
                shutil.rmtree(out, ignore_errors=True)
                removed += 1
        if everything:  # per-item results (recon.items) stay otherwise: they are what added photos reuse
            freed += _unshared_bytes((ws.meta / "items").rglob("*"))
            shutil.rmtree(ws.meta / "items", ignore_errors=True)
        if everything:
            (ws.meta / "state.json").unlink(missing_ok=True)
            for stage in REGISTRY.values():
                for link in stage.publish.values():
                    ws.unpublish(link)
        return removed, freed
