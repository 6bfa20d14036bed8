"""The ``recon`` command: parse, call the library, print. Errors are one line, never a traceback."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import signal
import sys
from pathlib import Path

from recon import api
from recon.config import ConfigError, describe, type_name
from recon.options import doc_of
from recon.products import Published
from recon.stage import StageError
from recon.workspace import WorkspaceError

log = logging.getLogger("recon")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="recon", description="Photogrammetry: photos -> cameras -> points -> mesh.")
    p.add_argument("-q", "--quiet", action="store_true", help="only warnings and errors")
    p.add_argument("-v", "--verbose", action="store_true", help="debug logs")
    sub = p.add_subparsers(dest="command", required=True)

    r = sub.add_parser("run", help="run a pipeline config (cached stages are skipped)")
    r.add_argument("config", help="YAML config, e.g. pipelines/sparse.yaml")
    r.add_argument("--images", help="folder of photos (overrides `images:`)")
    r.add_argument("--workspace", help="output folder (overrides `workspace:`)")
    r.add_argument("-o", "--override", action="append", default=[], metavar="KEY=VALUE",
                   help="override a config key, e.g. -o features.max_image_size=1600")
    r.add_argument("--from", dest="from_stage", metavar="STAGE", help="start at STAGE (earlier ones must be done)")
    r.add_argument("--until", metavar="STAGE", help="stop after STAGE")
    r.add_argument("--force", action="append", default=[], metavar="STAGE",
                   help="re-run STAGE and the stages after it even if cached")
    r.add_argument("--verify", action="store_true",
                   help="check every byte of cached outputs before reusing them (default: sizes, small files, "
                        "and files whose modification time moved)")

    s = sub.add_parser("status", help="per stage: done, stale (and why) or missing")
    s.add_argument("target", help="a config file or a workspace folder")
    s.add_argument("-o", "--override", action="append", default=[], metavar="KEY=VALUE")
    s.add_argument("--images")
    s.add_argument("--workspace")
    s.add_argument("--verify", action="store_true", help="check every byte of cached outputs")

    sub.add_parser("stages", help="list the stages, their inputs, outputs and options")

    c = sub.add_parser("clean", help="delete cached outputs the current config does not use")
    c.add_argument("target", help="a config file or a workspace folder")
    c.add_argument("--all", action="store_true", help="delete every cached output and the per-photo / per-pair / per-view results later runs reuse")
    c.add_argument("--workspace")

    e = sub.add_parser("eval", help="evaluate a workspace against ground truth")
    e.add_argument("workspace")
    e.add_argument("--gt", required=True, help="dataset folder, *_par.txt, Strecha folder, transforms.json "
                                              "or a synthetic scene")
    e.add_argument("--json", action="store_true", help="print JSON")

    y = sub.add_parser("synth", help="render a synthetic scene with ground truth (the seeded one, or a zoo scene)")
    y.add_argument("out", nargs="?", help="folder to write the scene into")
    y.add_argument("--scene", help="a zoo scene by name (see --list); without it, the seeded scene of --seed")
    y.add_argument("--list", action="store_true", help="list the zoo's scenes and what each one tests")
    y.add_argument("--views", type=int, default=None, help="regular views (default 24, or the zoo scene's own)")
    y.add_argument("--width", type=int, default=None, help="image width (default 640; 360: 1536)")
    y.add_argument("--height", type=int, default=None, help="image height (default 480; 360: 768)")
    y.add_argument("--camera", choices=["pinhole", "fisheye", "360"], default="pinhole",
                   help="fisheye: the seeded scene from its orbit through a 176-degree fisheye (20 views); "
                        "360: equirectangular panoramas walking through a room (16 views)")
    y.add_argument("--seed", type=int, default=0)
    y.add_argument("--holdout", type=int, default=None,
                   help="extra views held out for evaluation (default 0, or the zoo scene's own)")

    d = sub.add_parser("demo", help="render the demo scene if absent, reconstruct it, evaluate it")
    d.add_argument("--workspace", default="demo_workspace")
    d.add_argument("--config", default=None, help="pipeline config (default: pipelines/demo.yaml)")

    w = sub.add_parser("view", help="serve a workspace's report.html on localhost and print its address")
    w.add_argument("workspace")
    w.add_argument("--port", type=int, default=8000, help="port on 127.0.0.1 (0 = any free port)")

    lo = sub.add_parser("localize", help="place new photos in an existing reconstruction (poses.json + model)")
    lo.add_argument("workspace", help="workspace of a finished reconstruction (its sparse/0 and database.db)")
    lo.add_argument("photos", nargs="+", help="photo files, or one folder of photos")
    lo.add_argument("--out", help="output workspace (default: WORKSPACE/localize)")
    lo.add_argument("-o", "--override", action="append", default=[], metavar="KEY=VALUE",
                    help="override a config key, e.g. -o localize.min_inliers=20 (see `recon stages`)")
    lo.add_argument("--json", action="store_true", help="print poses.json")

    g = sub.add_parser("config", help="config tools")
    gsub = g.add_subparsers(dest="config_command", required=True)
    show = gsub.add_parser("show", help="print the resolved config with every default and its doc")
    show.add_argument("config", nargs="?")
    show.add_argument("-o", "--override", action="append", default=[], metavar="KEY=VALUE")
    return p


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    from recon.logs import setup_console

    setup_console(-1 if args.quiet else (1 if args.verbose else 0))
    _stop_on_sigterm()
    try:
        return _dispatch(args)
    except (ConfigError, StageError, WorkspaceError) as exc:
        print(f"recon: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head`
        return 0
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        print(f"recon: {'terminated (SIGTERM)' if terminated else 'interrupted'}; finished stages and items are "
              "kept: run the same command again to resume", file=sys.stderr)
        return 143 if terminated else 130
    except Exception as exc:  # a bug: one line for the user, the traceback in the log file
        log.debug("internal error", exc_info=True)
        from recon.logs import log_file

        where = log_file()
        print(f"recon: internal error: {type(exc).__name__}: {exc}"
              + (f" (traceback in {where})" if where else ""), file=sys.stderr)
        return 1


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, a batch scheduler, a container stopping): the run stops as on Ctrl-C."""


def _stop_on_sigterm() -> None:
    """Make SIGTERM stop recon as Ctrl-C does: finished stages and items kept, one line, exit 143.

    Importing pycolmap installs glog's failure-signal handler, SIGTERM included, which prints a
    native stack dump and kills the process; it is imported first so that this handler replaces it.
    """
    import pycolmap  # noqa: F401

    def terminated(signum, frame):
        raise Terminated

    signal.signal(signal.SIGTERM, terminated)


def _dispatch(args) -> int:
    if args.command == "run":
        result = api.run(args.config, images=args.images, workspace=args.workspace, overrides=args.override,
                         from_stage=args.from_stage, until=args.until, force=args.force, verify=args.verify)
        ran = ", ".join(result.ran) or "nothing (all cached)"
        print(f"recon: ran {ran}; workspace {result.workspace}")
        return 0
    if args.command == "status":
        rows = api.status(args.target, overrides=args.override, images=args.images, workspace=args.workspace,
                          verify=args.verify)
        width = max(len(r.name) for r in rows)
        for row in rows:
            print(f"{row.name:<{width}}  {row.state:<7}  {row.why}{f'; {row.reuse}' if row.reuse else ''}".rstrip())
        return 0
    if args.command == "stages":
        _print_stages()
        return 0
    if args.command == "clean":
        removed, freed = api.clean(args.target, everything=args.all, workspace=args.workspace)
        print(f"recon: removed {removed} cached output(s), {freed / 1e6:.1f} MB")
        return 0
    if args.command == "eval":
        figures = api.evaluate(args.workspace, args.gt)
        print(json.dumps(figures, indent=2) if args.json else format_eval(figures))
        return 0
    if args.command == "synth":
        from recon.synth import load_scene
        from recon.synth.zoo import zoo_list

        if args.list:
            for name, summary in zoo_list():
                print(f"{name:<16} {summary}")
            return 0
        if args.out is None:
            raise ConfigError("synth: give OUT, the folder to render the scene into (or --list to list the zoo)")
        out = api.synth(args.out, scene=args.scene, camera=args.camera, views=args.views, width=args.width,
                        height=args.height, seed=args.seed, holdout=args.holdout)
        info = load_scene(out)
        print(f"recon: rendered {info.name or 'the seeded scene'}, {info.views} views and {info.holdout} held out, "
              f"into {out}")
        return 0
    if args.command == "demo":
        figures = api.demo(args.workspace, args.config)
        print(format_eval(figures))
        ws = Path(args.workspace)
        for name in ("textured.glb", "report.html"):
            if (ws / name).exists():
                print(f"recon: {name}: {ws / name}")
        return 0
    if args.command == "view":
        return _view(Path(args.workspace), args.port)
    if args.command == "config":
        cfg = api.load(args.config, overrides=args.override)
        print("\n".join(describe(cfg.run)))
        for name, section in cfg.stages.items():
            print(f"{name}:")
            print("\n".join(describe(section, 1)))
        return 0
    if args.command == "localize":
        result = api.localize(args.workspace, args.photos, args.out, overrides=args.override)
        print(json.dumps(result, indent=2) if args.json else format_localize(result))
        return 0
    raise AssertionError(args.command)


def _view(workspace: Path, port: int) -> int:
    from recon.report.serve import report_server

    try:
        server, url = report_server(workspace, port)
    except FileNotFoundError:
        raise WorkspaceError(f"{workspace}: no report.html; run the pipeline with the report stage "
                             "(`until: report`, or `-o 'stages=[export, report]'`)") from None
    except OSError as exc:
        raise WorkspaceError(f"--port {port}: cannot listen on 127.0.0.1 ({exc.strerror}); "
                             "choose another port") from None
    print(f"recon: serving {workspace.absolute() / 'report.html'} at {url} (Ctrl-C to stop)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0


def format_eval(figures: dict) -> str:
    lines = []
    p = figures.get("poses")
    if p:
        lines.append(f"poses    registered {p['registered']}/{p['total']}   AUC@1/3/5 {p['auc@1']:.1f} / "
                     f"{p['auc@3']:.1f} / {p['auc@5']:.1f}   median camera-centre error "
                     f"{p['median_center_error']:.4g} ({100 * p['median_center_error_rel']:.3f}% of scale)")
    for key in ("fused", "mesh"):
        m = figures.get(key)
        if m:
            taus = sorted(float(k.split("@")[1]) for k in m if k.startswith("fscore@"))
            cells = "   ".join(f"@{100 * t:g}% of extent: accuracy {m[f'accuracy@{t:g}']:.1f} completeness "
                               f"{m[f'completeness@{t:g}']:.1f} F {m[f'fscore@{t:g}'] / 100:.3f}" for t in taus)
            lines.append(f"{key:<8} {cells}")
    r = figures.get("fused_reprojection")
    if r:
        lines.append(f"fused    reprojection into the ground-truth cameras: median {r['median_px']:.2f} px, "
                     f"90th percentile {r['p90_px']:.2f} px ({r['observations']} observations of "
                     f"{r['points']} points)")
    return "\n".join(lines)


def format_localize(result: dict) -> str:
    """Per photo: placed (inliers, camera centre) or refused (the reason); then where the outputs are."""
    width = max([len(p["name"]) for p in result["photos"]] + [4])
    lines = []
    for p in result["photos"]:
        if p["placed"]:
            centre = ", ".join(f"{v:.4g}" for v in p["centre"])
            lines.append(f"placed   {p['name']:<{width}}  {p['inliers']} inliers of {p['matches']} matches   "
                         f"centre ({centre})")
        else:
            lines.append(f"refused  {p['name']:<{width}}  {p['reason']}")
    ws = Path(result["workspace"])
    lines.append(f"recon: placed {result['placed']} of {result['total']} photo(s); poses in {ws / 'poses.json'}, "
                 f"model with them in {Published(ws).model()}")
    return "\n".join(lines)


def _print_stages() -> None:
    from recon.stage import REGISTRY, producer

    for name, stage in REGISTRY.items():
        print(f"{name} (v{stage.version}): {stage.summary}")
        inputs = [f"{p.__name__} ({producer(p)})" for p in stage.requires]
        inputs += [f"{p.__name__} ({producer(p)}, when part of the run)" for p in stage.optional]
        print(f"  inputs:  {', '.join(inputs) or 'the photo folder'}")
        print(f"  outputs: {stage.produces.__name__}: {', '.join(stage.produces.describe)}")
        for field in dataclasses.fields(stage.Config):
            default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
            print(f"    {name}.{field.name} ({type_name(stage.Config, field.name)}, default {default!r}): "
                  f"{doc_of(field)}")
        print()


if __name__ == "__main__":
    sys.exit(main())
