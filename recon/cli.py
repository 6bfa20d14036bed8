"""The ``recon`` command: parse, call the library, print. Errors are one line, never a traceback."""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
from pathlib import Path

from recon import api
from recon.config import ConfigError, describe, type_name
from recon.options import doc_of
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
    c.add_argument("--all", action="store_true", help="delete every cached output")
    c.add_argument("--workspace")

    e = sub.add_parser("eval", help="evaluate a workspace against ground truth")
    e.add_argument("workspace")
    e.add_argument("--gt", required=True, help="dataset folder, *_par.txt, Strecha folder, transforms.json "
                                              "or a synthetic scene")
    e.add_argument("--json", action="store_true", help="print JSON")

    y = sub.add_parser("synth", help="render a synthetic scene with ground truth")
    y.add_argument("out")
    y.add_argument("--views", type=int, default=24)
    y.add_argument("--width", type=int, default=640)
    y.add_argument("--height", type=int, default=480)
    y.add_argument("--seed", type=int, default=0)
    y.add_argument("--holdout", type=int, default=0, help="extra views held out for evaluation")

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
    try:
        return _dispatch(args)
    except (ConfigError, StageError, WorkspaceError) as exc:
        print(f"recon: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # output piped into `head`
        return 0
    except KeyboardInterrupt:
        print("recon: interrupted; finished stages and items are kept: run the same command again to resume",
              file=sys.stderr)
        return 130
    except Exception as exc:  # a bug: one line for the user, the traceback in the log file
        log.debug("internal error", exc_info=True)
        where = api.last_log_file()
        print(f"recon: internal error: {type(exc).__name__}: {exc}"
              + (f" (traceback in {where})" if where else ""), file=sys.stderr)
        return 1


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
            print(f"{row.name:<{width}}  {row.state:<7}  {row.why}".rstrip())
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
        print(json.dumps(figures, indent=2) if args.json else api.format_eval(figures))
        return 0
    if args.command == "synth":
        info = api.synth(args.out, views=args.views, width=args.width, height=args.height, seed=args.seed,
                         holdout=args.holdout)
        print(f"recon: rendered {args.views} views into {info}")
        return 0
    if args.command == "demo":
        figures = api.demo(args.workspace, args.config)
        print(api.format_eval(figures))
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
        print(json.dumps(result, indent=2) if args.json else api.format_localize(result))
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


def _print_stages() -> None:
    from recon.stage import REGISTRY

    for name, stage in REGISTRY.items():
        print(f"{name} (v{stage.version}): {stage.summary}")
        print(f"  inputs:  {', '.join(stage.requires) or 'the photo folder'}")
        print(f"  outputs: {', '.join(stage.outputs)}")
        for field in dataclasses.fields(stage.Config):
            default = field.default if field.default is not dataclasses.MISSING else field.default_factory()
            print(f"    {name}.{field.name} ({type_name(stage.Config, field.name)}, default {default!r}): "
                  f"{doc_of(field)}")
        print()


if __name__ == "__main__":
    sys.exit(main())
