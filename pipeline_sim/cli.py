"""The ``pipeline-sim`` command line: a thin layer over the Python API."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import importlib.metadata
import platform
import sys
import time
from pathlib import Path

from pipeline_sim.errors import OutputError, UserError
from pipeline_sim.memory import keep_freed_memory

EXIT_USER_ERROR = 2

DESCRIPTION = """\
Simulate a 5D (x, y, u, v, t) stochastic rasterization pipeline: triangle
setup -> tile traverser -> tile test -> z-cull -> sample tester -> shading
-> ROP, each unit a numba kernel on bounded SimPy queues. Renders motion
blur and depth of field from TOML scene files and reports what every unit
did (counters) and how long it took (simulated cycles).
"""

EPILOG = """\
'pipeline-sim COMMAND --help' gives each command's options and examples.
File formats: docs/README.md; outputs: docs/outputs.md; the machine it simulates: docs/pipeline.md.

example:
  pipeline-sim run workloads/scenes/default.toml --out runs/default
"""

#: Each command's own examples, shown by ``pipeline-sim COMMAND --help``.
EXAMPLES = {
    "run": ["pipeline-sim run workloads/scenes/default.toml --out runs/default",
            "pipeline-sim run workloads/scenes/static.toml --spp 4 --tile 16 --out runs/static",
            "pipeline-sim run workloads/scenes/motion.toml --set shading.cache_entries=512 "
            "--set zcull.time_slices=8 --out runs/motion"],
    "check": ["pipeline-sim check workloads/scenes/meshes.toml",
              "pipeline-sim check workloads/scenes/default.toml --spp 64 --set zcull.time_slices=8",
              "pipeline-sim check workloads/scenes/default.toml --set pass.shading_mode=per_sample "
              "--set pass.clip.t_hi=0.5 --set simulation.region_samples=0"],
    "arch": ["pipeline-sim arch --set tile_traverser.tile_size=16"],
    "warmup": ["pipeline-sim warmup"],
    "compare": ["pipeline-sim compare workloads/scenes/compare/motion_1x.toml --spp 4 --algorithms bbox hierarchical "
                "--out runs/compare"],
    "sweep": ["pipeline-sim sweep workloads/sweeps/quick.toml --out runs/quick",
              "pipeline-sim sweep workloads/sweeps/accuracy_cost.toml --out runs/study --executor dask",
              "pipeline-sim sweep s.toml --out runs/s --executor dask --scheduler tcp://10.0.0.5:8786"],
    "report": ["pipeline-sim report runs/quick -o runs/quick/report.html"],
}

SET_HELP = ("override one setting, repeatable: hardware as SECTION.KEY, the pass state as pass.KEY (pass.clip.KEY), "
            "simulation options as simulation.KEY (docs/architecture-format.md, docs/scene-format.md)")
FORCE_HELP = ("write into an existing folder that pipeline-sim did not write: its own files are replaced, nothing "
              "else there is removed (without it such a folder is refused)")


def _epilog(command: str) -> str:
    lines = EXAMPLES[command]
    return ("example:\n" if len(lines) == 1 else "examples:\n") + "".join(f"  {line}\n" for line in lines)


def _package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in ("numpy", "numba", "simpy", "pandas", "trimesh", "openexr", "pillow", "matplotlib"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            pass
    return out


def _load_inputs(args):
    """The workload file of ``args.scene`` with ``--spp``/``--seed``, on the architecture of
    ``--arch``, with the ``--set``/``--tile`` settings (hardware, pass state, simulation options)."""
    from pipeline_sim.config import load_arch
    from pipeline_sim.scene import check_image_value
    from pipeline_sim.workload import read_workload

    cls, data = read_workload(args.scene)
    image = {name: check_image_value(name, value, f"--{name}")
             for name, value in (("spp", args.spp), ("seed", args.seed)) if value is not None}
    overrides = list(args.set or [])
    if args.tile is not None:
        overrides.append(f"tile_traverser.tile_size={args.tile}")
    workload = cls.load(Path(args.scene), data, load_arch(args.arch), image).with_settings(overrides)
    return workload, workload.arch


def _progress_bar(quiet: bool):
    if quiet or not sys.stderr.isatty():
        return None, lambda: None
    from tqdm import tqdm

    bar = tqdm(total=0, unit="tri", desc="rendering", file=sys.stderr, leave=False)

    def update(done: int, total: int) -> None:
        bar.total = total
        bar.n = done
        bar.refresh()

    return update, bar.close


def cmd_run(args) -> int:
    workload, arch = _load_inputs(args)
    workload.check()  # all of it before a kernel module is imported

    from pipeline_sim.jit import warm_up
    from pipeline_sim.output import write_run
    from pipeline_sim.output_folder import OutputFolder
    from reports.run_report import summary_text

    with OutputFolder(args.out, "run", force=args.force) as out:
        compile_s = warm_up()
        if not args.quiet:
            print(f"numba kernels ready in {compile_s:.2f} s (compiled on first use, then loaded from cache)")
        update, close = _progress_bar(args.quiet)
        try:
            result = workload.run(progress=update)
        finally:
            close()
        info = {"compile_time_s": compile_s, "versions": _package_versions(), "command": sys.argv,
                "date": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        write_run(out.staging, workload, result, info)
        out.commit()
    if not args.quiet:
        print(summary_text(result, title=f"{args.scene} -> {args.out}"))
    return 0


def cmd_check(args) -> int:
    workload, _ = _load_inputs(args)
    print(f"{args.scene}: ok: {workload.check()}")
    return 0


def cmd_arch(args) -> int:
    import tomli_w

    from pipeline_sim.config import load_arch

    overrides = list(args.set or [])
    arch = load_arch(args.arch, overrides)
    sys.stdout.write(tomli_w.dumps(arch.to_dict()))
    return 0


def cmd_warmup(args) -> int:
    from pipeline_sim.jit import warm_up

    print(f"numba kernels ready in {warm_up():.2f} s")
    return 0


def cmd_compare(args) -> int:
    from pipeline_sim.accuracy import ReferenceSpec
    from pipeline_sim.compare import ALGORITHMS, format_checks, format_table, parse_algorithms, write_comparison
    from pipeline_sim.output_folder import OutputFolder

    algorithms = parse_algorithms(args.algorithms)
    workload, arch = _load_inputs(args)
    spec = ReferenceSpec(spp=args.reference_spp) if args.reference_spp else None
    scene = workload.reference_scene()
    if spec is not None and scene is None:
        raise UserError(f"--reference-spp: a workload of kind '{workload.kind}' has no single image to measure "
                        "against a reference")
    workload.check([workload.with_settings(ALGORITHMS[name]) for name in algorithms],
                   reference_spp=spec.spp if spec else None)
    with contextlib.ExitStack() as stack:
        out = stack.enter_context(OutputFolder(args.out, "compare", force=args.force)) if args.out else None
        comp, compile_s = _compare_all(args, workload, arch, algorithms, spec)
        info = {"scene": str(args.scene), "scene_digest": workload.digest, "kind": workload.kind,
                "workload": workload.resolved(), "arch": arch.to_dict(), "algorithms": algorithms,
                "compile_time_s": compile_s, "versions": _package_versions()}
        if scene is not None:
            info["image"] = dataclasses.asdict(scene.image)
        if out is not None:
            write_comparison(comp, out, info)
    if not args.quiet:
        print(format_table(comp.table))
        if comp.checks:
            print(format_checks(comp.checks))
        print(f"images identical across algorithms: {'yes' if comp.identical else 'NO'}"
              + (f" (differ: {', '.join(comp.differing)})" if comp.differing else ""))
    if not comp.identical:
        print(f"pipeline-sim: error: the image of {', '.join(comp.differing)} differs from the first algorithm "
              "run on the same samples: a culling test rejected a covered sample", file=sys.stderr)
        return 1
    return 0


def _compare_all(args, workload, arch, algorithms, spec):
    """Run ``workload`` with each algorithm (and render the reference ``spec``, if any); return the
    comparison and the kernels' compile time."""
    from pipeline_sim.accuracy import reference_image
    from pipeline_sim.compare import compare
    from pipeline_sim.jit import warm_up
    from reports.run_report import percent

    compile_s = warm_up()

    def progress(name, row):
        if not args.quiet:
            print(f"  {name}: STE {percent(row['ste'], 2)}, {row['samples_tested']:,} samples tested, "
                  f"{row['frame_cycles']:,.0f} cycles, {row['wall_time_s']:.2f} s", file=sys.stderr)

    reference = reference_image(workload.reference_scene(), spec, arch=arch) if spec is not None else None
    comp = compare(workload, arch, algorithms, progress=progress, reference=reference)
    return comp, compile_s


def cmd_sweep(args) -> int:
    from pipeline_sim.sweep import load_sweep, run_sweep

    spec = load_sweep(args.sweep)
    points = run_sweep(spec, args.out, executor=args.executor, workers=args.workers, scheduler=args.scheduler,
                       progress=not args.quiet, retry_errors=args.retry_errors, force=args.force)
    if not args.quiet:
        bad = int((points.status != "ok").sum())
        print(f"{len(points)} points in {Path(args.out) / 'points.csv'} ({bad} failed)")
    return 0


def cmd_report(args) -> int:
    folder = Path(args.sweep_dir)
    if (folder / "run.json").is_file() and not (folder / "sweep.json").exists():  # a run folder
        from reports.run_report import build_run_report

        if not args.out:  # its own report.html is the run's, listed in its marker
            raise UserError(f"{folder}: a run folder has its report (report.html); give -o FILE.html to write "
                            "it again elsewhere")
        path = build_run_report(folder, args.out, force=args.force)
        print(f"report: {path} (Markdown twin: {path.with_suffix('.md')})")
        return 0
    from reports.sweep_report import build_report

    out = Path(args.out) if args.out else folder / "report.html"
    path = build_report(args.sweep_dir, out, metric=args.metric, cost=args.cost, force=args.force)
    print(f"report: {path} (Markdown twin: {path.with_suffix('.md')})")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pipeline-sim", description=DESCRIPTION, epilog=EPILOG,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def scene_args(p, out: bool):
        p.add_argument("scene", metavar="FILE.toml", help="workload file: a scene (format: docs/scene-format.md) "
                       "or any workload kind (docs/workloads.md)")
        if out:
            p.add_argument("--out", "-o", required=True, metavar="DIR",
                           help="output folder: new, empty, or one pipeline-sim wrote (replaced whole when the run "
                           "succeeds); checked before the simulation starts")
            p.add_argument("--force", action="store_true", help=FORCE_HELP)
        p.add_argument("--spp", type=int, help="samples per pixel (overrides [image].spp)")
        p.add_argument("--seed", type=int, help="sampling seed (overrides [image].seed)")
        p.add_argument("--tile", type=int, help="tile size in pixels (same as --set tile_traverser.tile_size=N)")
        p.add_argument("--arch", metavar="FILE", help="architecture TOML applied over the shipped default")
        p.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE", help=SET_HELP)

    run = sub.add_parser("run", help="run a workload (a scene: one pass); write images, counters, timing, "
                         "results, run.json and a report",
                         description="Run the workload of FILE.toml (a scene, or any kind: docs/workloads.md) and "
                         "write into DIR, for each pass under passes/<pass>/: image.npy, image.exr (linear "
                         "float, RGBA unless the pass gives its first target other channels), image.png (8-bit "
                         "sRGB), counters.csv (one row per unit and counter), "
                         "timing.csv (busy/starved/blocked cycles per unit), queues.csv, trace.json; then "
                         "results.json (the workload's derived results), run.json (everything resolved: hardware, "
                         "every pass's state, the workload's content, versions, wall time) and "
                         "report.md/report.html. Formats: docs/outputs.md.",
                         epilog=_epilog("run"), formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_args(run, out=True)
    run.add_argument("--quiet", "-q", action="store_true", help="print nothing on success")
    run.set_defaults(func=cmd_run)

    check = sub.add_parser("check", help="validate a workload and architecture without simulating",
                           description="Load and validate FILE.toml and the architecture, as `run` would before "
                           "simulating; print a summary.", epilog=_epilog("check"),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_args(check, out=False)
    check.set_defaults(func=cmd_check)

    arch = sub.add_parser("arch", help="print the resolved architecture as TOML",
                          description="Print the architecture (shipped default, then --arch, then --set) as TOML.",
                          epilog=_epilog("arch"), formatter_class=argparse.RawDescriptionHelpFormatter)
    arch.add_argument("--arch", metavar="FILE", help="architecture TOML applied over the shipped default")
    arch.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE", help="override one hardware setting")
    arch.set_defaults(func=cmd_arch)

    from pipeline_sim.compare import ALGORITHMS, DESCRIPTIONS

    comp = sub.add_parser("compare", help="run a workload with each culling algorithm and compare their cost",
                          description="Run the workload of FILE.toml once per culling algorithm and print (and with --out, "
                          "save as table.csv, comparison.json, comparison.png and one image per algorithm) tiles "
                          "tested and rejected, samples tested and covered, STE, arithmetic by stage (triangle "
                          "setup, tile test, sample test, interpolation setup), depth-buffer bytes, shader "
                          "executions, simulated cycles and wall time. The images must be identical (every "
                          "algorithm is conservative); the command checks it and exits with status 1 if not. "
                          "Algorithms: " + "; ".join(f"{k}: {v}" for k, v in DESCRIPTIONS.items()),
                          epilog=_epilog("compare"),
                          formatter_class=argparse.RawDescriptionHelpFormatter)
    comp.add_argument("scene", metavar="FILE.toml", help="workload file (a scene or any kind)")
    comp.add_argument("--algorithms", nargs="+", metavar="NAME", choices=list(ALGORITHMS),
                      help=f"algorithms to compare (default: all of {', '.join(ALGORITHMS)})")
    comp.add_argument("--out", "-o", metavar="DIR",
                      help="write the table, chart and images here (new, empty, or a folder pipeline-sim wrote; "
                      "checked before the algorithms run)")
    comp.add_argument("--force", action="store_true", help=FORCE_HELP)
    comp.add_argument("--spp", type=int, help="samples per pixel (overrides [image].spp)")
    comp.add_argument("--seed", type=int, help="sampling seed (overrides [image].seed)")
    comp.add_argument("--tile", type=int, help="tile size in pixels")
    comp.add_argument("--reference-spp", type=int, metavar="N",
                      help="measure each image's error against a reference at N spp (default: against BBOX)")
    comp.add_argument("--arch", metavar="FILE", help="architecture TOML applied over the shipped default")
    comp.add_argument("--set", action="append", metavar="SECTION.KEY=VALUE", help=SET_HELP)
    comp.add_argument("--quiet", "-q", action="store_true", help="print nothing on success")
    comp.set_defaults(func=cmd_compare)

    sweep = sub.add_parser("sweep", help="run (or resume) a what-if sweep over scene and architecture settings",
                           description="Run every point of SWEEP.toml (format: docs/sweep-format.md) in its own "
                           "worker process and write DIR/points.csv (one row per point), DIR/results.csv (tidy: one "
                           "row per point and counter or metric) and DIR/points/<id>/ (image, error map, counters, "
                           "timing, trace, resolved config). Running the same command again resumes: finished "
                           "points are not recomputed. A failing point is recorded with its error and the sweep goes on.",
                           epilog=_epilog("sweep"),
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    sweep.add_argument("sweep", metavar="SWEEP.toml", help="sweep file")
    sweep.add_argument("--out", "-o", required=True, metavar="DIR",
                       help="results folder: new, empty, or an earlier run of the same sweep (resumed)")
    sweep.add_argument("--force", action="store_true",
                       help="write the sweep into an existing folder that holds other files: the sweep's own names "
                       "(sweep.json, points.csv, results.csv, points/, records/, reference/) are replaced there, "
                       "nothing else is touched")
    sweep.add_argument("--executor", choices=("local", "dask", "serial"), default="local",
                       help="local: a process pool on this machine (default); dask: a Dask cluster (--scheduler, or "
                       "a local cluster on 127.0.0.1); serial: in this process")
    sweep.add_argument("--workers", type=int, help="worker processes (default: the CPU count)")
    sweep.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address, e.g. tcp://host:8786")
    sweep.add_argument("--retry-errors", action="store_true", help="run points recorded as failed again")
    sweep.add_argument("--quiet", "-q", action="store_true", help="no progress output")
    sweep.set_defaults(func=cmd_sweep)

    report = sub.add_parser("report", help="write the HTML (and Markdown) report of a sweep or run folder",
                            description="Build a self-contained HTML report (figures embedded, no network "
                            "resources) and a Markdown twin from a run folder (-o required: the run's own report, "
                            "written again from its files) or from a sweep results folder: error against cost with "
                            "the Pareto frontier, counters, per-unit cycles and bottlenecks, parameters against "
                            "metrics, images with error maps, the pipeline and a timeline of one point.",
                            epilog=_epilog("report"),
                            formatter_class=argparse.RawDescriptionHelpFormatter)
    report.add_argument("sweep_dir", metavar="DIR", help="a folder written by `pipeline-sim sweep` or `run`")
    report.add_argument("--out", "-o", metavar="FILE.html",
                        help="output file (default: DIR/report.html); FILE.md and the folder FILE_files/ are "
                        "written beside it")
    report.add_argument("--force", action="store_true",
                        help="replace those outputs even where an existing one was not written by pipeline-sim")
    report.add_argument("--metric", default=None,
                        help="error metric: rmse, psnr, ssim, flip or a workload result column result.NAME "
                             "(default: the first of the sweep file's `results`, else flip)")
    report.add_argument("--cost", default="frame_cycles",
                        help="cost column: frame_cycles (default), ops_total or wall_time_s")
    report.set_defaults(func=cmd_report)

    warm = sub.add_parser("warmup", help="compile (or load from cache) all numba kernels and print the time",
                          description="Compile every numba kernel, or load it from the cache, and print the time.",
                          epilog=_epilog("warmup"), formatter_class=argparse.RawDescriptionHelpFormatter)
    warm.set_defaults(func=cmd_warmup)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if argv is None:  # the command itself, not a caller's process (tests call main with arguments)
        keep_freed_memory()
    try:
        return args.func(args)
    except UserError as exc:
        print(f"pipeline-sim: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except MemoryError:   # what the estimate could not foresee (docs/outputs.md): one line, not a traceback
        print("pipeline-sim: error: out of memory: the run needs more than this process may take; lower the "
              "image size, spp or simulation.region_samples", file=sys.stderr)
        return 1
    except OutputError as exc:   # the machine, not the input: a full disk, a folder made read-only mid-run
        print(f"pipeline-sim: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"pipeline-sim: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("pipeline-sim: interrupted (a sweep keeps its finished points: run it again to resume)",
              file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
