"""The ``nirc-bench`` command line (Typer).

Embedded by default: the SQLite database and artifacts live in the data folder
(``./data``, or ``NIRC_BENCH_DATA_DIR`` / ``--data-dir``), and jobs run through the
same executor the service workers use: ``render`` as the service runs a job, in a
render process of its own (jobs/execution/embedded.py), so that a native crash fails
the job with a record instead of killing the command; the other commands in this
process.

Errors a user can cause (unknown scene, malformed XML, bad numbers, a corrupt
EXR, no usable libLLVM, ...) print one line and exit with status 2; anything
else prints one line and exits 1 (``NIRC_BENCH_DEBUG=1`` shows the traceback).
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.markup import escape
from typer._click import exceptions as click_errors  # Typer's own copy of Click's

from renderers.methods import BASELINE, METHODS, sweep_methods
from service.cli_common import (
    REF_SPP,
    ApiKeyOpt,
    DataDir,
    JsonOut,
    RefSpp,
    Server,
    console,
    err_console,
    number_in,
    open_settings,
    open_store,
    print_json,
    submit_and_wait,
)
from service.errors import UsageError, describe_user_error, is_user_error
from service.progress import progress_reporter
from service.reproduce_command import reproduce_app
from service.runs_command import parse_pairs, runs_app
from service.tables import metrics_table, reference_table, render_tables, scenes_table

if TYPE_CHECKING:
    from service.config import ServiceSettings

app = typer.Typer(
    name="nirc-bench",
    help="Evaluate and benchmark radiance-caching renderers against converged references.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,      # help is plain text: 'a:b:step' is not an emoji code
    add_completion=False,
)
Scene = Annotated[str, typer.Option("--scene", "-s", help="built-in scene name or XML path")]
Res = Annotated[int, typer.Option("--res", help="image width and height", min=1, max=8192)]
MaxDepth = Annotated[int, typer.Option(
    "--max-depth", min=-1, max=1024,
    help="longest path in segments for renders, cache-training paths and the reference "
         "alike (-1 = unbounded: Russian roulette ends paths)")]
MethodMaxDepth = Annotated[int | None, typer.Option(
    "--max-depth", min=-1, max=1024,
    help="longest path in segments for the render, its cache-training paths and the "
         "reference alike (-1 = unbounded: Russian roulette ends paths); default: the "
         "method's own (-1; 2 for the direct-light methods)")]


@dataclass(frozen=True)
class Remote:
    """How a command shows what a service ran for it: the API path of the finished
    job's result (from the job's JSON) and how to print it (client, the job's JSON, the
    result's JSON, the local scene file's path or None)."""

    result_path: Callable[[dict[str, Any]], str]
    show: Callable[[Any, dict[str, Any], dict[str, Any], str | None], None]


def _run_remote(server: str, api_key: str | None, queued: Any, as_json: bool,
                remote: Remote) -> None:
    """Submit the typed job ``queued`` (jobs.execution.queued) to the service at ``server``,
    follow its progress, print the result."""
    from renderers.scenes import is_scene_file
    from service.client import ServiceClient

    client = ServiceClient(server, api_key)
    local_scene: str | None = None
    spec = queued.stored()
    if is_scene_file(spec["scene"]):   # a local scene file: the service gets a copy
        uploaded = client.upload_scene(spec["scene"])
        # The table names the file as a local run does (its path here); the service's
        # run names the copy, and the content fingerprint is the file's in both.
        local_scene = str(Path(spec["scene"]).expanduser().resolve())
        if not as_json:
            console.print(f"scene {Path(spec['scene']).name} uploaded as {uploaded} (the "
                          "same content fingerprint as a local run of the file)",
                          markup=False, highlight=False)
        spec = {**spec, "scene": uploaded}
    job = submit_and_wait(client, queued.kind, spec, server, as_json)
    result = client.get(remote.result_path(job))
    if as_json:
        print_json(result)
        return
    remote.show(client, job, result, local_scene)


def _print_remote_run(_client: Any, _job: dict[str, Any], result: dict[str, Any],
                      local_scene: str | None) -> None:
    """The run's table as an embedded render prints it, from the same public model the
    API serves."""
    from jobs.protocol.results import RunResultDetail

    shown = result if local_scene is None else {**result, "scene": local_scene}
    console.print(metrics_table(RunResultDetail.model_validate(shown)))


def _print_remote_sweep(client: Any, job: dict[str, Any], sweep: dict[str, Any],
                        local_scene: str | None) -> None:
    """The sweep's table as an embedded run prints it (``local_scene``: the path of an
    uploaded scene file, named as a local run names it); its files are the service's
    artifacts (URLs), and the stages of ``job`` (as ``GET /jobs/{id}`` lists them)
    are named."""
    from jobs.sweeps.sweep import SweepResult
    from service.tables import sweep_table

    files = {a["kind"]: f"{client.http.base_url}{a['url']}" for a in sweep["artifacts"]}
    shown = {**sweep["result"], "files": files,
             **({"scene": local_scene} if local_scene is not None else {})}
    console.print(sweep_table(SweepResult.model_validate(shown)))
    stages = job.get("stages") or []
    if stages:
        console.print(f"ran on the service as {len(stages)} stage jobs "
                      f"({', '.join(stage['name'] for stage in stages)}) and the sweep job "
                      f"{job['id']}",
                      markup=False, highlight=False)


_REMOTE_RUN = Remote(lambda job: f"/api/v1/runs/{job['run_id']}", _print_remote_run)
_REMOTE_SWEEP = Remote(lambda job: f"/api/v1/sweeps/{job['sweep_id']}", _print_remote_sweep)


def _run(server: str | None, api_key: str | None, queued: Any, remote: Remote, as_json: bool,
         data_dir: Path | None, job: Callable[[Any, Any, Any], Any],
         to_json: Callable[[Any], Any], table: Callable[[Any], Any],
         out: Path | None = None) -> None:
    """Submit the typed job ``queued`` to ``server`` if given, else run ``job`` here
    (see below)."""
    if server and out is not None:
        raise UsageError("--out writes local files: it cannot be used with --server "
                         "(fetch results from the service's /api/v1 instead)")
    if server:
        _run_remote(server, api_key, queued, as_json, remote)
    else:
        _run_embedded(job, data_dir, as_json, to_json, table)


def _run_embedded(job: Callable[[Any, Any, Any], Any], data_dir: Path | None, as_json: bool,
                  to_json: Callable[[Any], Any], table: Callable[[Any], Any]) -> Any:
    """Run ``job(store, settings, progress)`` here (``render``'s job hands its render to
    a render process of its own) and print its result (JSON, or the table; progress
    bars unless JSON)."""
    settings = open_settings(data_dir)
    store = open_store(settings)
    with progress_reporter(console, quiet=as_json) as report:
        result = job(store, settings, report)
    if as_json:
        print_json(to_json(result))
    else:
        console.print(table(result))
    return result


@app.command()
def scenes(
    as_json: JsonOut = False,
    res: Annotated[int, typer.Option(
        "--res", min=1, max=8192, help="width and height the scenes are loaded at (the "
                                       "fingerprints and features do not depend on it)")] = 64,
) -> None:
    """List the built-in scenes with their fingerprints and features."""
    from renderers.backend import init_backend
    from renderers.scenes import builtin_names, load_scene

    init_backend()
    loaded = [load_scene(name, res) for name in builtin_names()]
    if as_json:
        print_json([scene.to_json() for scene in loaded])
    else:
        console.print(scenes_table(loaded))


@app.command()
def methods(
    name: Annotated[str | None, typer.Argument(help="a method: list its parameters")] = None,
    as_json: JsonOut = False,
) -> None:
    """The registered methods, or one method's parameters with their defaults, and what
    each needs of a scene."""
    from service.method_info import method_info
    from service.tables import methods_table

    infos = [method_info(name)] if name else [method_info(n) for n in METHODS]
    if as_json:
        print_json(infos if name is None else infos[0])
    else:
        console.print(methods_table(infos))


@app.command()
def reference(
    scene: Scene,
    res: Res = 64,
    spp: Annotated[int, typer.Option("--spp", min=8, max=1 << 24, help="target spp")] = 4096,
    max_depth: MaxDepth = -1,
    integrator: Annotated[str, typer.Option("--integrator", help="'path' (Mitsuba) or 'pt'")] = "path",
    rel_stderr: Annotated[float | None, typer.Option(
        "--rel-stderr", parser=number_in(0.0), metavar="FLOAT",
        help="stop early below this relative standard error (>= 0)")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="copy the reference EXR here")] = None,
    as_json: JsonOut = False,
    data_dir: DataDir = None,
) -> None:
    """Render (or reuse) the converged reference of a scene."""
    from jobs.protocol.references import get_or_render_reference
    from jobs.protocol.spec import ReferenceSpec
    from renderers.backend import init_backend
    from renderers.scenes import load_scene

    spec = ReferenceSpec(integrator=integrator, spp=spp, rel_stderr=rel_stderr)
    settings = open_settings(data_dir)
    init_backend()
    loaded = load_scene(scene, res)
    store = open_store(settings)
    with progress_reporter(console, quiet=as_json) as report:
        ref = get_or_render_reference(
            store, settings.references_dir, loaded, spec.settings(max_depth),
            progress=lambda done, total: report("reference", done, total))
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ref.image_path, out)
        shutil.copyfile(ref.image_path.with_suffix(".variance.exr"),
                        out.with_name(out.stem + ".variance.exr"))
    info = {"scene": loaded.name, "fingerprint": loaded.fingerprint, "key": ref.key,
            "spp": ref.spp, "split_half": ref.split_half, "reused": not ref.rendered_now,
            "path": str(out or ref.image_path)}
    if as_json:
        print_json(info)
    else:
        console.print(reference_table(info))


def _parse_param(text: str) -> tuple[str, Any]:
    if "=" not in text:
        raise typer.BadParameter(f"expected NAME=VALUE, got '{text}'", param_hint="--param")
    name, value = text.split("=", 1)
    try:
        return name.strip(), json.loads(value)
    except json.JSONDecodeError:
        return name.strip(), value


def _parse_sweep(text: str) -> Any:
    """``--sweep NAME=VALUES``: a range or comma list of numbers (integers where every
    value is one), else a comma list of JSON values or words."""
    from jobs.protocol.ranges import RangeError, parse_range
    from jobs.protocol.spec import ParameterSweep

    name, sep, values = text.partition("=")
    if not sep or not name.strip() or not values.strip():
        raise typer.BadParameter(f"expected NAME=VALUES, got '{text}'", param_hint="--sweep")
    for integer in (True, False):
        with contextlib.suppress(RangeError):
            return ParameterSweep(name=name.strip(), values=parse_range(values, integer=integer))
    return ParameterSweep(name=name.strip(),
                          values=[_parse_param(f"v={word}")[1] for word in values.split(",")])


def _shortcut_help(field: str, what: str) -> str:
    """Help of a parameter shortcut: which methods have ``field`` (from the registry)."""
    names = [name for name, method in METHODS.items() if field in method.params.model_fields]
    return f"{', '.join(names)}: {what} (same as -p {field}=...)"


def _knob_help(spp: bool = True) -> str:
    """The knobs of the registry, each with the methods that have it ('spp (pt, ...)')."""
    owners: dict[str, list[str]] = {}
    for name, method in METHODS.items():
        if method.knob is not None and (spp or method.knob.name != "spp"):
            owners.setdefault(method.knob.name, []).append(method.knob.requirement or name)
    return ", ".join(f"{knob} ({', '.join(names)})" for knob, names in owners.items())


def _parse_nc(text: str) -> list[int]:
    try:
        return [int(part) for part in text.split(",")]
    except ValueError:
        raise typer.BadParameter(f"expected integers like '4' or '3,1,1', got '{text}'",
                                 param_hint="--nc") from None


@app.command()
def render(
    scene: Scene,
    method: Annotated[str, typer.Option(
        "--method", "-m", help=f"one of {', '.join(METHODS)}")] = BASELINE,
    res: Res = 64,
    spp: Annotated[int, typer.Option("--spp", min=1, max=1 << 16, help="spp per frame")] = 1,
    frames: Annotated[int, typer.Option("--frames", min=1, max=100_000,
                                        help="frames per seed, accumulated")] = 1,
    seeds: Annotated[int, typer.Option("--seeds", min=1, max=1000, help="K independent renders")] = 4,
    max_depth: MethodMaxDepth = None,
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", help="method parameter NAME=VALUE (repeatable)")] = None,
    estimator: Annotated[str | None, typer.Option(
        "--estimator", help=_shortcut_help("estimator", "'biased' or 'unbiased'"))] = None,
    termination: Annotated[str | None, typer.Option(
        "--termination", help=_shortcut_help("termination", "path termination"))] = None,
    nc: Annotated[str | None, typer.Option(
        "--nc", help=_shortcut_help("nc", "N_c: '4' (biased) or per vertex '3,1,1' "
                                          "(unbiased)"))] = None,
    pretrain: Annotated[int | None, typer.Option(
        "--pretrain", min=0, max=100_000,
        help=_shortcut_help("pretrain_frames", "cache training frames before timing"))] = None,
    ref_spp: RefSpp = REF_SPP,
    eps: Annotated[float, typer.Option("--eps", parser=number_in(1e-9, 1.0), metavar="FLOAT",
                                       help="MRSE epsilon, in [1e-9, 1]")] = 0.01,
    budget_ms: Annotated[float | None, typer.Option(
        "--budget-ms", parser=number_in(1e-6, 1e7), metavar="FLOAT",
        help=f"equal time: calibrate {_knob_help()} to this ms per frame (1e-6 to 1e7)")
    ] = None,
    budget_pt_spp: Annotated[int | None, typer.Option(
        "--budget-pt-spp", min=1, max=1 << 16,
        help="equal time: calibrate to the frame time of PT at this spp")] = None,
    allow_loaded: Annotated[bool, typer.Option(
        "--allow-loaded", help="equal time: use calibration probes timed on a loaded machine "
                               "(default: left out and taken again)")] = False,
    denoised: Annotated[bool | None, typer.Option(
        "--denoised/--no-denoised", show_default=False,
        help="also score each seed's last frames after Intel Open Image Denoise (MRSE and "
             "FLIP of one frame and of four accumulated; default: the spec's, off)")] = None,
    out: Annotated[Path | None, typer.Option("--out", help="write images and summary.json here")] = None,
    rerun: Annotated[bool, typer.Option(
        "--rerun", help="render even if a run of this spec by this commit, estimator "
                        "version and device is stored (default: reuse it)")] = False,
    name: Annotated[str | None, typer.Option("--name", help="name the stored run")] = None,
    tag: Annotated[list[str] | None, typer.Option(
        "--tag", help="KEY=VALUE tag of the stored run (repeatable)")] = None,
    as_json: JsonOut = False,
    data_dir: DataDir = None,
    server: Server = None,
    api_key: ApiKeyOpt = None,
) -> None:
    """Render a method over K seeds, compare with the reference, store the run. A run of
    the same spec stored by the same commit, estimator version and device is reused
    (and said so) unless --rerun. The render runs in a process of its own: if it
    crashes, the job is stored as failed with the signal and the stage it was in."""
    from jobs.execution.embedded import RenderFailed, render_here
    from jobs.execution.queued import QueuedRender
    from jobs.protocol.job import RenderJob
    from jobs.protocol.spec import ReferenceSpec, RenderSpec, TimeBudget

    params = dict(_parse_param(p) for p in param or [])
    if max_depth is not None:
        params.setdefault("max_depth", max_depth)
    shortcuts = {"estimator": estimator, "termination": termination,
                 "nc": _parse_nc(nc) if nc is not None else None, "pretrain_frames": pretrain}
    params.update({name: value for name, value in shortcuts.items() if value is not None})
    budget = (TimeBudget(ms=budget_ms, pt_spp=budget_pt_spp, allow_loaded=allow_loaded)
              if budget_ms is not None or budget_pt_spp is not None else None)
    if allow_loaded and budget is None:
        raise UsageError("--allow-loaded applies to an equal-time calibration: give "
                         "--budget-ms or --budget-pt-spp")
    spec = RenderSpec(scene=scene, method=method, params=params, resolution=res, spp=spp,
                      frames=frames, seeds=seeds, eps=eps, reference=ReferenceSpec(spp=ref_spp),
                      time_budget=budget,
                      **({} if denoised is None else {"denoised": denoised}))
    queued = QueuedRender(job=RenderJob.parse(spec))    # parsed once, here
    tags = parse_pairs(tag, "--tag")
    if server and rerun:
        raise UsageError("--rerun: the service keeps one job per spec and answers an "
                         "identical one with it; change the spec (e.g. --seeds) to render "
                         "again there")
    if server and (name or tags):
        raise UsageError("--name and --tag label a run in the local data folder; with "
                         "--server, label it there (`nirc-bench runs tag` on its machine)")

    def job(store: Any, settings: Any, report: Any) -> Any:
        summary = render_here(queued.job, store, settings, report, reuse=not rerun,
                              out_dir=out)
        if name is not None or tags:
            stored = store.label_run(summary.run_id, name=name, set_tags=tags)
            summary.result = summary.result.model_copy(
                update={"name": stored.name, "tags": stored.tags})
        return summary

    try:
        _run(server, api_key, queued, _REMOTE_RUN, as_json, data_dir, job,
             lambda s: s.to_json(), render_tables, out)
    except RenderFailed as err:
        if err.user_error:
            raise UsageError(str(err)) from None
        err_console.print(f"nirc-bench: {err}", markup=False, highlight=False, soft_wrap=True)
        raise typer.Exit(1) from None
    if out is not None and not as_json:
        console.print(f"images and summary.json written to {out}")


@app.command()
def evaluate(
    reference_path: Annotated[Path, typer.Option("--reference", "-r", help="reference EXR")],
    image: Annotated[Path, typer.Option("--image", "-i", help="test EXR")],
    eps: Annotated[float, typer.Option(
        "--eps", parser=number_in(1e-9, 1.0), metavar="FLOAT",
        help="epsilon of the relative errors, (X-R)^2/(R^2+eps), in [1e-9, 1]")] = 0.01,
    as_json: JsonOut = False,
) -> None:
    """Compute MSE, MRSE, FLIP and non-finite counts of an image against a reference."""
    from metrics.errors import image_metrics
    from metrics.flip import hdr_exposures
    from metrics.imageio import read_exr

    ref = read_exr(reference_path)
    test = read_exr(image)
    values = image_metrics(test, ref, eps=eps, flip_exposures=hdr_exposures(ref))
    values.update(reference=str(reference_path), image=str(image), eps=eps)
    if as_json:
        print_json(values)
    else:
        from service.tables import key_value_table

        console.print(key_value_table("metrics", values))


@app.command()
def report(
    scene: Scene,
    res: Res = 64,
    frames: Annotated[int, typer.Option("--frames", min=1, max=100_000,
                                        help="frames per seed")] = 16,
    seeds: Annotated[int, typer.Option("--seeds", min=1, max=1000,
                                       help="K independent renders per method")] = 2,
    pretrain: Annotated[int, typer.Option(
        "--pretrain", min=0, max=100_000,
        help="frames the caches train before the rendered frames (pretrain_frames)")] = 100,
    max_depth: MaxDepth = -1,
    ref_spp: RefSpp = REF_SPP,
    allow_loaded: Annotated[bool, typer.Option(
        "--allow-loaded", help="use timings taken on a loaded machine for the equal-time "
                               "rows (default: left out and listed)")] = False,
    max_pt_spp: Annotated[int | None, typer.Option(
        "--max-pt-spp", min=1, max=1_000_000,
        help="largest spp a PT calibration tries (a PT row that would need more is "
             "flagged capped: less than equal time; default: the knob's candidates)")] = None,
    strongest: Annotated[str | None, typer.Option(
        "--strongest", help="comma list of the strongest PT's candidates to calibrate "
                            "(default: all of pt, pt-power, pt-spatial)")] = None,
    as_json: JsonOut = False,
    data_dir: DataDir = None,
) -> None:
    """Compare PT, NRC and NIRC on a scene (NIRC paper Fig. 7): equal spp and equal time."""
    from jobs.pareto.report import comparison_report
    from jobs.views.baselines import pt_core_methods
    from service.tables import comparison_tables

    candidates = None if strongest is None else \
        tuple(dict.fromkeys(m.strip() for m in strongest.split(",") if m.strip()))
    if candidates is not None and (not candidates or set(candidates) - set(pt_core_methods())):
        raise UsageError(f"--strongest: give one or more of {', '.join(pt_core_methods())}")
    _run_embedded(
        lambda store, settings, report: comparison_report(
            scene, store, settings, resolution=res, frames=frames, seeds=seeds,
            pretrain_frames=pretrain, max_depth=max_depth, ref_spp=ref_spp, progress=report,
            allow_loaded=allow_loaded, max_pt_spp=max_pt_spp, strongest=candidates),
        data_dir, as_json, lambda r: r.model_dump(mode="json"), comparison_tables)


@app.command()
def sweep(
    scene: Scene,
    eps: Annotated[str | None, typer.Option(
        "--eps", help="relative-bias thresholds of the adaptive equal-bias protocol: "
                      "'0.05:1.0' (step = start, inclusive), 'a:b:step' or 'a,b,c'")] = None,
    nc: Annotated[str | None, typer.Option(
        "--nc", help="N_c values ('1:32', '1,2,4'): a biased-NIRC sweep, or with --eps the "
                     "candidates of the 'NIRC equal time' series (default 1,2,4,8,16,32)")] = None,
    sweep_parameter: Annotated[str | None, typer.Option(
        "--sweep", help="a parameter sweep: NAME=VALUES over a parameter every method of "
                        "--methods declares, e.g. 'sph_c=0.01,0.1,1' or a range 'a:b:step'")] = None,
    methods: Annotated[str, typer.Option(
        "--methods", help=f"comma list of {', '.join(sweep_methods())} (any method for "
                          "--sweep)")] = ",".join(sweep_methods()),
    res: Res = 64,
    seeds: Annotated[int, typer.Option("--seeds", min=2, max=1000,
                                       help="K independent caches and renders")] = 4,
    frames: Annotated[int, typer.Option("--frames", min=1, max=100_000,
                                        help="1-spp frames per point")] = 1,
    train_frames: Annotated[int, typer.Option("--train-frames", min=1, max=100_000,
                                              help="online-training frames per cache")] = 100,
    v1_spp: Annotated[int, typer.Option("--v1-spp", min=2, max=1 << 20,
                                        help="spp of the converged cache-at-v1 images")] = 256,
    bias_definition: Annotated[str, typer.Option(
        "--bias-definition", help="per-pixel bias of the v1 mask: 'relative-mse' or "
                                  "'authors' (docs/protocol.md)")] = "relative-mse",
    max_depth: MaxDepth = -1,
    termination: Annotated[str | None, typer.Option(
        "--termination", help="N_c sweep: the termination policy (its method's "
                               "'termination' parameter; default: that method's)")] = None,
    equal_time: Annotated[bool, typer.Option(
        "--equal-time/--no-equal-time", help="add the 'NIRC equal time' series")] = True,
    tolerance_ms: Annotated[float, typer.Option(
        "--tolerance-ms", parser=number_in(0.0, 1e6), metavar="FLOAT",
        help="equal time within this many ms (0 to 1e6)")] = 1.0,
    allow_loaded: Annotated[bool, typer.Option(
        "--allow-loaded", help="equal time: use calibration probes timed on a loaded machine "
                               "(default: left out and taken again)")] = False,
    param: Annotated[list[str] | None, typer.Option(
        "--param", "-p", help="parameter for every method NAME=VALUE (repeatable)")] = None,
    ref_spp: RefSpp = REF_SPP,
    out: Annotated[Path | None, typer.Option(
        "--out", help="write plots and result.json here (default: data/sweeps/sweep-<id>)")] = None,
    as_json: JsonOut = False,
    data_dir: DataDir = None,
    server: Server = None,
    api_key: ApiKeyOpt = None,
) -> None:
    """Run the adaptive equal-bias sweep (NIRC paper Sec. 6.3, Fig. 13), an N_c sweep or a
    sweep over one parameter (--sweep).

    References, trained caches and converged cache-at-v1 images are computed once
    and reused; points already stored are not rendered again.
    """
    from jobs.execution.queued import QueuedSweep
    from jobs.protocol.ranges import RangeError, parse_range
    from jobs.protocol.spec import ReferenceSpec, SweepSpec
    from jobs.sweeps.sweep import run_sweep
    from service.tables import sweep_table

    if eps is None and nc is None and sweep_parameter is None:
        raise RangeError("give --eps (adaptive equal-bias sweep) and/or --nc (N_c sweep), "
                         "or --sweep NAME=VALUES")

    def parsed(text: str | None, option: str, integer: bool = False) -> list | None:
        try:
            return parse_range(text, integer=integer) if text is not None else None
        except RangeError as err:
            raise RangeError(f"{option}: {err}") from None

    spec = SweepSpec(
        scene=scene, eps=parsed(eps, "--eps"), nc=parsed(nc, "--nc", integer=True),
        parameter=_parse_sweep(sweep_parameter) if sweep_parameter is not None else None,
        methods=[m.strip() for m in methods.split(",") if m.strip()], resolution=res,
        seeds=seeds, frames=frames, train_frames=train_frames, v1_spp=v1_spp,
        max_depth=max_depth, equal_time=equal_time,
        **({"termination": termination} if termination is not None else {}),
        time_tolerance_ms=tolerance_ms, allow_loaded=allow_loaded,
        params=dict(_parse_param(p) for p in param or []),
        reference=ReferenceSpec(spp=ref_spp), bias_definition=bias_definition)
    _run(server, api_key, QueuedSweep(spec=spec), _REMOTE_SWEEP, as_json, data_dir,
         lambda store, settings, report: run_sweep(spec, store, settings, progress=report,
                                                   out_dir=out),
         lambda r: r.to_json(), sweep_table, out)


def _counts(text: str, option: str, what: str) -> list[int]:
    """The integers >= 1 of a range like '1,2,4' or '1:32' given to ``option``."""
    from jobs.protocol.ranges import RangeError, parse_range

    try:
        values = parse_range(text, integer=True)
    except RangeError as err:
        raise RangeError(f"{option}: {err}") from None
    if min(values) < 1:
        raise RangeError(f"{option}: '{text}': {what} must be >= 1")
    return values


def _resolution(text: str, option: str) -> tuple[int, int]:
    """'1920x1080' given to ``option``: width and height, each 1..16384."""
    from jobs.protocol.ranges import RangeError

    width, sep, height = text.lower().partition("x")
    if not sep or not width.strip().isdigit() or not height.strip().isdigit():
        raise RangeError(f"{option}: '{text}' is not WIDTHxHEIGHT (e.g. 1920x1080)")
    size = int(width), int(height)
    if not all(1 <= n <= 16384 for n in size):
        raise RangeError(f"{option}: '{text}': width and height must be 1..16384")
    return size


def _parse_knob_values(texts: list[str]) -> dict[str, list[int]]:
    """``--knob-values``: 'METHOD=1,4,16' for one method, or '1,4,16' for every method
    with an equal-time knob other than the baseline (the registry's)."""
    from jobs.pareto.plan import knob_methods

    values: dict[str, list[int]] = {}
    for text in texts:
        name, _, listed = text.rpartition("=")
        parsed = _counts(listed, "--knob-values", "knob values")
        names = [name.strip()] if name else knob_methods()
        values.update(dict.fromkeys(names, parsed))
    return values


@app.command()
def pareto(
    scene: Scene,
    res: Res = 32,
    frames: Annotated[int, typer.Option("--frames", min=1, max=100_000,
                                        help="timed frames per seed")] = 8,
    seeds: Annotated[int, typer.Option("--seeds", min=2, max=1000,
                                       help="K independent renders (the CI resamples them)")] = 2,
    pt_spp: Annotated[str, typer.Option(
        "--pt-spp", help=f"spp values of the baseline ({BASELINE}): '1,2,4,8,16' or '1:16'")]
        = "1,2,4,8,16",
    knob_values: Annotated[list[str] | None, typer.Option(
        "--knob-values", help=f"equal-time knob values, METHOD=LIST (repeatable) or LIST for "
                              f"every method with a knob other than spp: {_knob_help(spp=False)} "
                              "(default: the registry's candidates; spp knobs take --pt-spp)")]
        = None,
    methods: Annotated[str | None, typer.Option(
        "--methods", help=f"comma list of methods (default: all of {', '.join(METHODS)})")]
        = None,
    pretrain: Annotated[int, typer.Option(
        "--pretrain-frames", min=0, max=100_000,
        help="cache training frames before the timed frames (not per-frame time)")] = 16,
    max_depth: MaxDepth = -1,
    ref_spp: RefSpp = REF_SPP,
    timing_rounds: Annotated[int, typer.Option(
        "--timing-rounds", min=0, max=100,
        help="interleaved timing rounds after the runs (each point's time is their median; "
             "measured on every call, also for reused runs; 0: the run's own per-seed "
             "frame times)")] = 3,
    probe_frames: Annotated[int, typer.Option("--probe-frames", min=1, max=1000,
                                              help="timed frames per timing probe")] = 3,
    resamples: Annotated[int, typer.Option("--resamples", min=100, max=100_000,
                                           help="bootstrap resamples of the speed-up CI")]
        = 2000,
    project_res: Annotated[str | None, typer.Option(
        "--project-res", help="also project each point's ms/frame to this resolution, e.g. "
                              "1920x1080, from its per-stage cost model measured on this "
                              "device (docs/timing.md)")] = None,
    cost_res: Annotated[str, typer.Option(
        "--cost-res", help="square resolutions the cost model is fitted from "
                           "(with --project-res)")] = "64,128,256",
    out: Annotated[Path | None, typer.Option(
        "--out", help="write pareto.json, pareto_mrse.png and pareto_flip.png here")] = None,
    baseline: Annotated[str, typer.Option(
        "--baseline", help="what speed-ups are measured against: strongest-pt (the lower "
                           "envelope of the PT methods with throughput roulette), paper-pt "
                           "(pt's fixed roulette) or a series' label")] = "strongest-pt",
    without_stage: Annotated[list[str] | None, typer.Option(
        "--without-stage", help="also show each point that runs this stage with the stage's "
                                "time taken out, as a series of its own off the fronts (e.g. "
                                "propagation: grid-cache without its propagation pass); "
                                "repeatable")] = None,
    allow_loaded: Annotated[bool, typer.Option(
        "--allow-loaded", help="put points timed on a loaded machine on the fronts, baselines "
                               "and speed-ups (default: marked and left out)")] = False,
    as_json: JsonOut = False,
    data_dir: DataDir = None,
) -> None:
    """Error against seconds per frame (online training included): PT at several spp and
    every caching method at several knob values, the Pareto front, and each method's
    speed-up at equal MRSE / FLIP over the strongest PT (or --baseline) with a bootstrap
    CI; the paper's PT is a series of its own (docs/pareto.md). A point
    stored by an earlier call (same spec, scene, reference, device) is reused. With
    --project-res, each point's frame time projected to that resolution (labelled as a
    projection from this device; the errors stay those measured at --res)."""
    from jobs.pareto.plan import ParetoSpec, plan

    spp_values = _counts(pt_spp, "--pt-spp", "spp values")
    spec = ParetoSpec(
        scene=scene, resolution=res, frames=frames, seeds=seeds, pt_spp=spp_values,
        knob_values=_parse_knob_values(knob_values or []),
        methods=[m.strip() for m in methods.split(",") if m.strip()] if methods else None,
        pretrain_frames=pretrain, max_depth=max_depth, ref_spp=ref_spp,
        timing_rounds=timing_rounds, probe_frames=probe_frames, resamples=resamples,
        project_res=_resolution(project_res, "--project-res") if project_res else None,
        cost_resolutions=_counts(cost_res, "--cost-res", "resolutions"), baseline=baseline,
        without_stages=list(dict.fromkeys(without_stage or [])), allow_loaded=allow_loaded)
    plan(spec)      # bad options fail before anything that renders is imported
    from jobs.pareto.pareto import run_pareto
    from service.pareto_table import pareto_table

    _run_embedded(
        lambda store, settings, report: run_pareto(spec, store, settings, progress=report,
                                                   out_dir=out),
        data_dir, as_json, lambda r: r.to_json(), pareto_table)


@app.command()
def ci(
    suite: Annotated[Path, typer.Option("--suite", help="the pinned suite (TOML)")]
        = Path("ci/suite.toml"),
    baseline: Annotated[Path, typer.Option(
        "--baseline", help="baseline file to compare with (or to write)")]
        = Path("ci/baseline.json"),
    baseline_ref: Annotated[str | None, typer.Option(
        "--baseline-ref", help="compare with the latest stored results of this commit or "
                               "branch instead of the baseline file")] = None,
    update_baseline: Annotated[bool, typer.Option(
        "--update-baseline", help="run every entry at the seed cap and write --baseline")]
        = False,
    seed_start: Annotated[int, typer.Option(
        "--seed-start", min=0, max=1 << 20,
        help="first seed (the baseline's seeds give a paired comparison)")] = 0,
    summary: Annotated[Path | None, typer.Option(
        "--summary", help="also write the Markdown summary here")] = None,
    junit: Annotated[Path | None, typer.Option("--junit", help="write JUnit XML here")] = None,
    soak: Annotated[bool, typer.Option(
        "--soak/--no-soak", help="run the suite's soak ([soak]) after the gate")] = True,
    data_dir: DataDir = None,
    server: Server = None,
    api_key: ApiKeyOpt = None,
) -> None:
    """Regression gate: run a pinned suite, adding seeds until each row is decided, and
    compare with a baseline (docs/ci.md); then the suite's soak, if it has one (every
    method for many frames, docs/soak.md). Exit 0: pass, 1: a regression or a soak
    problem, 2: could not run."""
    from jobs.ci.ci_suite import CiError
    from service.ci_command import CiOptions, run_ci

    options = CiOptions(suite=suite, baseline=baseline, baseline_ref=baseline_ref,
                        update_baseline=update_baseline, seed_start=seed_start,
                        summary=summary, junit=junit, data_dir=data_dir, server=server,
                        api_key=api_key, soak=soak)
    try:
        code = run_ci(options, console, err_console)
    except Exception as err:  # noqa: BLE001 - exit 1 means a regression: all else is 2
        if os.environ.get("NIRC_BENCH_DEBUG"):
            raise
        message = (describe_user_error(err) if is_user_error(err, CiError.__module__ + "."
                                                                   + CiError.__qualname__)
                   else f"{type(err).__name__}: {err}")
        err_console.print(f"nirc-bench ci: could not run: {message}", markup=False,
                          highlight=False, soft_wrap=True)
        raise typer.Exit(2) from None
    raise typer.Exit(code)


TlsCaFile = Annotated[Path | None, typer.Option(
    "--tls-ca-file", help="tls:// scheduler: the CA that signed the scheduler's and workers' "
                          "certificates (or NIRC_BENCH_TLS_CA_FILE)")]
TlsCert = Annotated[Path | None, typer.Option(
    "--tls-cert", help="tls:// scheduler: this process's certificate, PEM "
                       "(or NIRC_BENCH_TLS_CERT)")]
TlsKey = Annotated[Path | None, typer.Option(
    "--tls-key", help="tls:// scheduler: its private key, PEM (or NIRC_BENCH_TLS_KEY)")]
AllowPlaintext = Annotated[bool, typer.Option(
    "--allow-plaintext-scheduler",
    help="connect to a tcp:// scheduler off loopback, unencrypted and unauthenticated: "
         "anyone who reaches it runs code on the workers (or "
         "NIRC_BENCH_ALLOW_PLAINTEXT_SCHEDULER=true)")]


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or 'localhost') reaches this machine only."""
    import ipaddress

    host = host.strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:      # a name: it may resolve to any interface
        return False


def decide_public_read(choice: bool | None, host: str) -> bool:
    """Whether reads need no API key: as chosen, else only on a loopback address."""
    if choice is not None:
        return choice
    if is_loopback(host):
        return True
    raise UsageError(
        f"--host {host} is reachable from other machines: choose whether anyone who can "
        "reach it may read results, jobs (specs, errors, worker addresses) without an API "
        "key: --public-read or --no-public-read (or NIRC_BENCH_PUBLIC_READ=true/false)")


def decide_allowed_hosts(choice: list[str] | None, host: str) -> list[str]:
    """The Host header values the service answers to: as chosen, else loopback names
    and the address it binds to; a wildcard address names no host, so a choice is
    required there."""
    from service.config import LOOPBACK_HOSTS

    if choice is not None:
        return choice
    if host.strip("[]") in ("0.0.0.0", "::", ""):
        raise UsageError(
            f"--host {host} listens on every interface: name the hosts clients reach the "
            "service by, with --allowed-hosts NAME,... (or NIRC_BENCH_ALLOWED_HOSTS; '*' "
            "for any, which lets a web page reach it through a domain of its own)")
    return list(dict.fromkeys([*LOOPBACK_HOSTS, host]))


def _with_tls(settings: ServiceSettings, scheduler: str, ca_file: Path | None,
              cert: Path | None, key: Path | None,
              allow_plaintext: bool = False) -> ServiceSettings:
    """``settings`` with the TLS files of a tls:// ``scheduler`` (options over the
    environment's settings), checked; a plain scheduler off loopback is refused unless
    ``allow_plaintext`` (or the setting of that name) accepts it, with a warning."""
    if allow_plaintext:
        settings = settings.model_copy(update={"allow_plaintext_scheduler": True})
    files = {"tls_ca_file": ca_file or settings.tls_ca_file,
             "tls_cert": cert or settings.tls_cert, "tls_key": key or settings.tls_key}
    given = {name: path for name, path in files.items() if path is not None}
    if scheduler.startswith("tls://"):
        if len(given) < 3:
            raise UsageError("a tls:// scheduler needs --tls-ca-file, --tls-cert and --tls-key "
                             "(or NIRC_BENCH_TLS_CA_FILE, NIRC_BENCH_TLS_CERT, "
                             "NIRC_BENCH_TLS_KEY)")
        for path in given.values():
            if not Path(path).is_file():
                raise UsageError(f"TLS file {path} not found")
    elif given:
        raise UsageError(f"TLS certificates are for a tls:// scheduler address, not "
                         f"'{scheduler}' (start the scheduler with --protocol tls)")
    elif not is_loopback(scheduler.split("://", 1)[-1].rsplit(":", 1)[0]):
        if not settings.allow_plaintext_scheduler:
            raise UsageError(
                f"the scheduler {scheduler} is neither encrypted nor authenticated: anyone "
                "who reaches it runs code on the workers. Use tls:// with certificates "
                "(docs/security.md), or accept that risk with --allow-plaintext-scheduler "
                "(NIRC_BENCH_ALLOW_PLAINTEXT_SCHEDULER=true)")
        err_console.print(f"nirc-bench: warning: the scheduler {scheduler} is not encrypted "
                          "or authenticated (allowed by allow_plaintext_scheduler): anyone "
                          "who reaches it runs code on the workers",
                          markup=False, highlight=False)
    return settings.model_copy(update=given)


@app.command()
def serve(
    host: Annotated[str, typer.Option(
        "--host", help="address to listen on (off loopback, choose --public-read or "
                       "--no-public-read)")] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", min=1, max=65535,
                                      help="port to listen on")] = 8000,
    scheduler: Annotated[str | None, typer.Option(
        "--scheduler", help="Dask scheduler address, tls://HOST:8786 with the --tls-* options "
                            "(default: an embedded LocalCluster)")] = None,
    job_timeout: Annotated[float | None, typer.Option(
        "--job-timeout", parser=number_in(1.0), metavar="FLOAT",
        help="seconds before an attempt is killed (>= 1)")] = None,
    gpus: Annotated[int | None, typer.Option(
        "--gpus", min=0, max=64,
        help="GPU workers of the embedded cluster (default: one per GPU found)")] = None,
    public_read: Annotated[bool | None, typer.Option(
        "--public-read/--no-public-read",
        help="whether reads (results, jobs, the dashboard) need no API key (default: only "
             "on a loopback --host; elsewhere a choice is required; or "
             "NIRC_BENCH_PUBLIC_READ)")] = None,
    allowed_hosts: Annotated[str | None, typer.Option(
        "--allowed-hosts",
        help="comma-separated host names the service answers to (the Host header; '*' any); "
             "default: localhost, 127.0.0.1, ::1 and --host (or NIRC_BENCH_ALLOWED_HOSTS)")]
        = None,
    tls_ca_file: TlsCaFile = None,
    tls_cert: TlsCert = None,
    tls_key: TlsKey = None,
    allow_plaintext_scheduler: AllowPlaintext = False,
    dask_dashboard: Annotated[bool, typer.Option(
        "--dask-dashboard",
        help="keep the embedded cluster's Dask dashboards, on loopback ports, open to every "
             "account of this machine (or NIRC_BENCH_DASK_DASHBOARD=true)")] = False,
    key_quota_bytes: Annotated[int | None, typer.Option(
        "--key-quota-bytes", min=0,
        help="bytes each API key's results, uploads and unfinished jobs may take on disk "
             "(0: no quota; default 10 GiB, or NIRC_BENCH_KEY_QUOTA_BYTES)")] = None,
    data_dir: DataDir = None,
) -> None:
    """Run the service: REST API (OpenAPI at /docs) + job queue on Dask."""
    from service.config import ServiceSettings

    settings = ServiceSettings.of(open_settings(data_dir))
    # Decided before anything starts: an open service must be asked for, not stumbled on.
    public = decide_public_read(public_read if public_read is not None
                                else settings.public_read, host)
    if scheduler and gpus is not None:
        raise UsageError("--gpus sizes the embedded cluster; with --scheduler, run "
                         "`nirc-bench worker --scheduler ... --gpus N` on the GPU machines")
    if scheduler:
        settings = _with_tls(settings, scheduler, tls_ca_file, tls_cert, tls_key,
                             allow_plaintext_scheduler)
    elif tls_ca_file or tls_cert or tls_key:
        raise UsageError("--tls-* options are for a tls:// --scheduler; the embedded cluster "
                         "stays on loopback")
    if dask_dashboard:
        if scheduler:
            raise UsageError("--dask-dashboard is for the embedded cluster; a --scheduler's "
                             "dashboard is its own (`dask scheduler --dashboard-address`)")
        settings = settings.model_copy(update={"dask_dashboard": True})
    given = {name: value for name, value in (("allowed_hosts", allowed_hosts),
                                             ("key_quota_bytes", key_quota_bytes))
             if value is not None}
    if given:
        settings = ServiceSettings.model_validate({**settings.model_dump(), **given})
    hosts = decide_allowed_hosts(settings.allowed_hosts, host)
    settings = settings.model_copy(update={"public_read": public, "allowed_hosts": hosts})

    import uvicorn

    from jobs.execution.dispatch import Dispatcher
    from service.api.main import create_app
    from service.slow_clients import ClientDeadlines

    os.umask(0o077)     # references, logs, snapshots: owner-only, like the database
    dispatcher = Dispatcher(settings, scheduler, timeout_s=job_timeout, gpus=gpus,
                            tls=settings.scheduler_tls, dashboard=settings.dask_dashboard)
    if dispatcher.dashboard_url:
        err_console.print(f"nirc-bench: Dask dashboard at {dispatcher.dashboard_url} (open to "
                          "every account of this machine)", markup=False, highlight=False)
    deadlines = ClientDeadlines(settings.header_timeout_s, settings.body_window_s,
                                settings.body_min_bytes_per_s)
    try:
        uvicorn.run(create_app(settings, dispatcher), host=host, port=port,
                    http=deadlines.protocol(settings.max_connections))
    finally:
        dispatcher.close()


@app.command()
def worker(
    scheduler: Annotated[str, typer.Option("--scheduler", help="tls://HOST:8786 (or tcp://)")],
    gpus: Annotated[int, typer.Option("--gpus", min=0, max=64,
                                      help="one worker per GPU, each with resource GPU=1")] = 0,
    tls_ca_file: TlsCaFile = None,
    tls_cert: TlsCert = None,
    tls_key: TlsKey = None,
    allow_plaintext_scheduler: AllowPlaintext = False,
) -> None:
    """Run Dask worker(s) for a service started with --scheduler (same data folder):
    one CPU worker, or one per GPU, each seeing only its GPU (CUDA_VISIBLE_DEVICES)."""
    from jobs.execution.dispatch import QUIET_WORKER_CONFIG, dask_environment, worker_tls_options
    from jobs.execution.gpus import run_workers, worker_commands
    from service.config import ServiceSettings

    settings = _with_tls(ServiceSettings.of(open_settings(None)), scheduler, tls_ca_file,
                         tls_cert, tls_key, allow_plaintext_scheduler)
    tls = worker_tls_options(settings.scheduler_tls)
    # Dask's worker HTTP pages (info, logs, health, metrics) are unauthenticated and
    # listen on every interface: none are served unless the variable says otherwise.
    environment = {"DASK_DISTRIBUTED__WORKER__HTTP__ROUTES": "[]", **os.environ,
                   **dask_environment(QUIET_WORKER_CONFIG)}
    commands = [([*argv, *tls], env) for argv, env in worker_commands(
        scheduler, gpus, environment)]
    os.umask(0o077)     # what the workers write into the data folder: owner-only
    if len(commands) == 1:      # nothing to supervise: become the worker
        argv, env = commands[0]
        os.execve(sys.executable, argv, env)
    raise typer.Exit(run_workers(commands))


@app.command()
def gc(
    apply_: Annotated[bool, typer.Option("--apply", help="remove (default: only list what "
                                                         "would be removed)")] = False,
    keep_days: Annotated[float | None, typer.Option(
        "--keep-days", parser=number_in(0.0), metavar="FLOAT",
        help="keep anything younger (>= 0; default: the gc_keep_days setting)")] = None,
    data_dir: DataDir = None,
) -> None:
    """Free disk: remove references no run uses, stored scenes and files no stored row
    names (older than --keep-days), and results' artifacts and reproduced figures past
    the retention policy (artifact_keep_days, artifact_max_bytes). Lists them with sizes;
    removes them only with --apply."""
    from jobs.record import gc as retention

    settings = open_settings(data_dir)
    store = open_store(settings)
    try:
        plan = retention.plan(store, settings, keep_days)
        for removal in plan.removals:
            console.print(f"{removal.bytes:>14,d}  {removal.what:<15} {removal.name}",
                          markup=False, highlight=False)
        if not apply_:
            console.print(f"would remove {len(plan.removals)} items, {plan.bytes:,d} bytes "
                          "(run with --apply to remove them)", markup=False, highlight=False)
            return
        freed = retention.apply(store, settings, plan)
        console.print(f"removed {len(plan.removals)} items, {freed:,d} bytes",
                      markup=False, highlight=False)
    finally:
        store.close()


@app.command()
def stress(
    case: Annotated[list[str] | None, typer.Option(
        "--case", help="a stress case (repeat; default: all, docs/stress.md)")] = None,
    res: Annotated[int | None, typer.Option(
        "--res", min=4, max=512, help="resolution (default 16; --soak 32)")] = None,
    spp: Annotated[int, typer.Option("--spp", min=1, max=1024, help="spp per frame")] = 4,
    frames: Annotated[int | None, typer.Option(
        "--frames", min=1, max=4096, help="frames (default 2, at most 64; --soak 64)")] = None,
    seeds: Annotated[int | None, typer.Option(
        "--seeds", min=1, max=64, help="seeds (default 8, at least 2; --soak 4)")] = None,
    reference_spp: Annotated[int | None, typer.Option(
        "--reference-spp", min=8, max=1 << 20, help="reference spp (default 1024; --soak 64)"
    )] = None,
    soak: Annotated[bool, typer.Option(
        "--soak", help="the soak instead: every method for many frames (docs/soak.md)")] = False,
    method: Annotated[list[str] | None, typer.Option(
        "--method", help="with --soak: a method to soak (repeat; default: all)")] = None,
    as_json: JsonOut = False,
    server: Server = None,
    api_key: ApiKeyOpt = None,
    data_dir: DataDir = None,
) -> None:
    """Run adversarial scenes through every registered method and print, per case and
    method, non-finite pixels, losses and skipped steps, the largest pixel, agreement of
    unbiased methods and what the user is told. Exits 1 if a method crashed, a non-finite
    value reached a metric or cache weight, or an unbiased method disagreed where it must
    agree. With --soak: every method rendered for many frames as `render` renders it;
    exits 1 on a crash, a non-finite value, or a recording after the warm-up."""
    if soak:
        if case or server:
            raise UsageError("--soak runs on this machine over the built-in scenes: "
                             "--case and --server do not apply")
        _soak(res, frames, seeds, reference_spp, method, as_json, data_dir)
        return
    if method:
        raise UsageError("--method applies to --soak only (the stress suite runs every method)")
    res, frames = res or 16, frames or 2
    seeds, reference_spp = seeds or 8, reference_spp or 1024
    if frames > 64 or seeds < 2:
        raise UsageError("the stress suite takes at most 64 frames and at least 2 seeds")
    from jobs.stress.stress import (
        EmbeddedBackend,
        StressSettings,
        get_cases,
        markdown_table,
        run_suite,
    )

    settings = StressSettings(resolution=res, spp=spp, frames=frames, seeds=seeds,
                              reference_spp=reference_spp)
    cases = get_cases(case)
    if server:
        from service.client import ServiceClient
        from service.stress_remote import RemoteBackend

        backend: Any = RemoteBackend(ServiceClient(server, api_key))
    else:
        from renderers.backend import init_backend

        init_backend()
        paths = open_settings(data_dir)
        backend = EmbeddedBackend(open_store(paths), paths)
    progress = None if as_json else (lambda what: err_console.print(
        f"stress: {what}", markup=False, highlight=False))
    report = run_suite(backend, settings, cases, progress)
    if as_json:
        print_json({**report.model_dump(mode="json"), "problems": report.problems()})
    else:
        console.print(markdown_table(report), markup=False, highlight=False, soft_wrap=True)
        for problem in report.problems():
            console.print(f"problem: {problem}", markup=False, highlight=False, soft_wrap=True)
    if report.problems():
        raise typer.Exit(1)


def _soak(res: int | None, frames: int | None, seeds: int | None,
          reference_spp: int | None, methods: list[str] | None, as_json: bool,
          data_dir: Path | None) -> None:
    """``stress --soak``: jobs.stress.soak through the CLI's own render (a render process
    per job), printed as a table or JSON; exits 1 on a problem."""
    from jobs.execution.embedded import render_here
    from jobs.protocol.scene_store import builtin_features
    from jobs.stress.soak import SoakSettings, markdown_table, run_soak

    unknown = [name for name in methods or () if name not in METHODS]
    if unknown:
        raise UsageError(f"unknown method(s) {', '.join(unknown)}; choose from "
                         f"{', '.join(METHODS)}")
    wanted = {"resolution": res, "frames": frames, "seeds": seeds,
              "reference_spp": reference_spp}
    settings = SoakSettings(**{k: v for k, v in wanted.items() if v is not None})
    paths = open_settings(data_dir)
    store = open_store(paths)
    progress = None if as_json else (lambda what: err_console.print(
        f"soak: {what}", markup=False, highlight=False))
    try:
        report = run_soak(lambda job: render_here(job, store, paths), builtin_features,
                          settings, methods, progress)
    finally:
        store.close()
    if as_json:
        print_json({**report.model_dump(mode="json"), "problems": report.problems()})
    else:
        console.print(markdown_table(report), markup=False, highlight=False, soft_wrap=True)
        for problem in report.problems():
            console.print(f"problem: {problem}", markup=False, highlight=False, soft_wrap=True)
    if report.problems():
        raise typer.Exit(1)


app.add_typer(runs_app, name="runs")
app.add_typer(reproduce_app, name="reproduce")
apikey_app = typer.Typer(help="API keys of the service's write endpoints.", no_args_is_help=True,
                         rich_markup_mode=None)
app.add_typer(apikey_app, name="apikey")


@apikey_app.command("list")
def apikey_list(as_json: JsonOut = False, data_dir: DataDir = None) -> None:
    """The keys: name, prefix, admin or not, when created and revoked (never the key)."""
    from jobs.execution.apikeys import list_api_keys

    keys = [{"name": k.name, "prefix": k.prefix, "admin": k.admin, "created": k.created_at,
             "revoked": k.revoked_at}
            for k in list_api_keys(open_store(open_settings(data_dir)))]
    if as_json:
        print_json(keys)
        return
    from rich.table import Table

    table = Table(title=f"{len(keys)} API keys")
    for column in ("name", "prefix", "admin", "created", "revoked"):
        table.add_column(column)
    for key in keys:
        table.add_row(*(escape("-" if v is None else v.strftime("%Y-%m-%d %H:%M")
                               if hasattr(v, "strftime") else str(v)) for v in key.values()))
    console.print(table)


@apikey_app.command("create")
def apikey_create(
    name: Annotated[str, typer.Option("--name", help="who or what uses the key")] = "default",
    admin: Annotated[bool, typer.Option(
        "--admin", help="may also cancel jobs that other keys submitted")] = False,
    data_dir: DataDir = None,
) -> None:
    """Create a key; it is printed once and stored only as a digest."""
    from jobs.execution.apikeys import create_api_key

    row, key = create_api_key(open_store(open_settings(data_dir)), name, admin=admin)
    console.print(key, markup=False, highlight=False)
    err_console.print(f"{'admin ' if admin else ''}API key '{name}' created (prefix "
                      f"{row.prefix}); it is not shown again.")


@apikey_app.command("revoke")
def apikey_revoke(prefix: Annotated[str, typer.Argument(help="the key's prefix")],
                  data_dir: DataDir = None) -> None:
    """Revoke a key by its prefix (the part after 'nb_')."""
    from jobs.execution.apikeys import revoke_api_key

    if not revoke_api_key(open_store(open_settings(data_dir)), prefix):
        raise UsageError(f"no active API key with prefix '{prefix}'")
    console.print(f"revoked {prefix}")


def main() -> None:
    """Console-script entry point: run the app, turning errors into one-line messages
    (the options' own checks included: one line naming the option, exit status 2)."""
    try:
        code = app(prog_name="nirc-bench", standalone_mode=False)
    except click_errors.NoArgsIsHelpError as err:
        console.print(err.format_message(), markup=False, highlight=False, emoji=False)
        sys.exit(2)
    except click_errors.UsageError as err:
        command = err.ctx.command_path if err.ctx else "nirc-bench"
        err_console.print(f"nirc-bench: error: {err.format_message()} (see {command} --help)",
                          markup=False, highlight=False, soft_wrap=True)
        sys.exit(2)
    except typer.Abort:
        err_console.print("nirc-bench: aborted", markup=False, highlight=False)
        sys.exit(130)
    except Exception as err:  # noqa: BLE001 - the last line of defence: one line, no traceback
        if is_user_error(err):
            err_console.print(f"nirc-bench: error: {describe_user_error(err)}", markup=False,
                              highlight=False, soft_wrap=True)  # one line, not wrapped at 80
            sys.exit(2)
        if os.environ.get("NIRC_BENCH_DEBUG"):
            raise
        err_console.print(
            f"nirc-bench: internal error ({type(err).__name__}): {err} "
            "(set NIRC_BENCH_DEBUG=1 for the traceback)", markup=False, highlight=False,
            soft_wrap=True)
        sys.exit(1)
    sys.exit(code or 0)
