"""The `rodctl` command line. Each command is a thin function: load the config, call in.

Bad input (a missing file, invalid YAML, an unknown key, a value out of range, a malformed `--set`)
raises `UserError`; `user_errors` turns it into one short message on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import json
import math
import os
import sys
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer

from rodctl.config import ExperimentConfig, dump_config, load_config
from rodctl.errors import (
    RunFailed,
    UserError,
    describe_os_error,
    make_out_folder,
    out_error,
    out_path,
)
from rodctl.executors.base import sigterm_as_interrupt

F = TypeVar("F", bound=Callable[..., Any])


def _plain_help() -> None:
    """typer 0.29 shows a required argument as `{config}` in the usage line and `<bool>` beside
    every flag in --help; show CONFIG, and nothing beside a flag, as click does."""
    from typer import core

    def usage_name(self: Any) -> str:
        name = self.display_name_raw.upper()
        name = name if self.required else f"[{name}]"
        return name + ("..." if self.nargs != 1 else "")

    option_type = core.TyperOption.display_type_rich

    def flag_type(self: Any, ctx: Any) -> str | None:
        return None if self.is_flag and self.metavar is None else option_type(self, ctx)

    # typer's own classes, patched on purpose (the usage line and the flags' help)
    core.TyperArgument._usage_display_name = usage_name  # type: ignore[method-assign]
    core.TyperOption.display_type_rich = flag_type  # type: ignore[method-assign]


_plain_help()

# Markdown: docstring paragraphs are reflowed to the terminal (no line broken mid-sentence);
# an indented block (the examples) is shown as written.
app = typer.Typer(
    name="rodctl",
    help="Experiment runner for vision-based shape servoing of elastic rods.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    rich_markup_mode="markdown",
)
config_app = typer.Typer(
    help="Inspect configs: print a resolved config or the JSON schema.",
    no_args_is_help=True,
    rich_markup_mode="markdown",
)
app.add_typer(config_app, name="config")

ConfigArg = Annotated[str, typer.Argument(help="YAML config file, e.g. configs/default.yaml.")]
SetOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override one key: --set a.b=value (value parsed as YAML). Repeatable.",
        metavar="KEY=VALUE",
    ),
]


def user_errors(fn: F) -> F:
    """Turn the two kinds of expected failure into one line on stderr, never a traceback:
    bad input (`UserError`) exits 2; a run that could not go on (`RunFailed`, or an `OSError`
    such as a full disk or a read-only folder) or was interrupted (a KeyboardInterrupt the
    command did not handle, named by its signal: `sigterm_as_interrupt`) exits 1."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except UserError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        except RunFailed as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=1) from None
        except KeyboardInterrupt as exc:  # one no command handled: its signal, exit 1
            typer.echo(f"error: interrupted by {str(exc) or 'SIGINT'}", err=True)
            raise typer.Exit(code=1) from None
        except BrokenPipeError:
            # The reader went away (`rodctl config show … | head`): what it read was right.
            # Point stdout at /dev/null so the interpreter's final flush does not fail again.
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            raise typer.Exit(code=0) from None
        except OSError as exc:
            typer.echo(f"error: {describe_os_error(exc)}", err=True)
            raise typer.Exit(code=1) from None

    return wrapper  # type: ignore[return-value]


def _version(value: bool) -> None:
    if value:
        from rodctl import __version__

        typer.echo(f"rodctl {__version__}")
        raise typer.Exit()


@app.callback()
def _startup(
    ctx: typer.Context,
    version: Annotated[
        bool,
        typer.Option(
            "--version", callback=_version, is_eager=True, help="Print the version and exit."
        ),
    ] = False,
    allow_override: Annotated[
        bool,
        typer.Option(
            "--allow-override",
            help="Let plug-ins replace built-in stage types (warned on stderr and recorded in "
            "meta.json and run.mcap); also RODCTL_ALLOW_OVERRIDE=1. Off: such a plug-in is "
            "refused (exit 2).",
        ),
    ] = False,
) -> None:
    """Experiment runner for vision-based shape servoing of elastic rods."""
    import os

    from rodctl.registry import ALLOW_OVERRIDE_ENV, load_plugins

    if allow_override:
        os.environ[ALLOW_OVERRIDE_ENV] = "1"  # worker processes inherit it
    if ctx.invoked_subcommand == "plugins":
        return  # it lists every plug-in, the failed ones too, and then exits 2 for them
    try:
        load_plugins()
    except UserError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None


@app.command()
def plugins() -> None:
    """List every registered type (feature, estimator, controller, event, sink, executor), and
    where it comes from."""
    import textwrap

    from rodctl.registry import KINDS, load_plugins, plugin_provenance

    failures = load_plugins(strict=False)
    provenance = plugin_provenance()
    overridden = {(o["kind"], o["type"]) for o in provenance["overrides"]}
    width = max((len(reg.type) for registry in KINDS.values() for reg in registry), default=0)
    for kind, registry in KINDS.items():
        typer.echo(f"{kind}:")
        for reg in registry:
            default = " (default)" if reg.type == registry.default else ""
            if (kind, reg.type) in overridden:
                default += " (REPLACES the built-in: --allow-override)"
            typer.echo(f"  {reg.type:<{width}}  {reg.source}{default}")
            indent = " " * (width + 4)
            if reg.summary:
                typer.echo(
                    textwrap.fill(
                        reg.summary,
                        100,
                        initial_indent=indent,
                        subsequent_indent=indent,
                        break_on_hyphens=False,
                    )
                )
    if provenance["loaded"]:
        typer.echo("plug-ins loaded:")
    for p in provenance["loaded"]:
        typer.echo(f"  {p['distribution']} {p['version']} ({p['value']}): {p['file']}")
        typer.echo(f"    sha256 {p['sha256']}")
    for f in failures:
        typer.echo(f"failed plug-in {f.name} ({f.value}): {f.error}", err=True)
    if failures:
        raise typer.Exit(code=2)


def _config_model(path: str) -> type:
    """The model a config file is for: a sweep config has `parameters`, a compare config
    `methods`, any other is an experiment."""
    from rodctl.config import read_yaml
    from rodctl.config.compare import CompareConfig
    from rodctl.config.sweep import SweepConfig

    data = read_yaml(path)
    if "parameters" in data:
        return SweepConfig
    return CompareConfig if "methods" in data else ExperimentConfig


@config_app.command("show")
@user_errors
def config_show(config: ConfigArg, set_: SetOpt = None) -> None:
    """Print the resolved config (YAML, every default filled in but the physics switched off:
    gravity, material, table friction, a second arm, the quasi-static engine) after --set
    overrides.

    Works for experiment configs (simulate, train-encoder) and compare configs alike.
    """
    model = _config_model(config)
    if model is ExperimentConfig:
        cfg = load_config(config, set_ or [])
        derived = _derived_values(cfg)
    elif model.__name__ == "SweepConfig":
        from rodctl.bench.sweep import load_sweep_config

        cfg = load_sweep_config(config, set_ or [])
        derived = {}
    else:
        from rodctl.bench.compare import load_compare_config

        cfg = load_compare_config(config, set_ or [])
        derived = {}
    typer.echo(dump_config(cfg, clean=True), nl=False)
    if derived:
        typer.echo("# derived from the keys above where they are null (set them to override):")
        for key, value in derived.items():
            typer.echo(f"#   {key}: {value}")


def _derived_values(cfg: ExperimentConfig) -> dict[str, Any]:
    """What the null keys resolve to when the run starts (shown by `config show`)."""
    from rodctl.sim.rod import home_pose, time_step
    from rodctl.vision.camera import principal_point

    def clean(v: float) -> float:
        return float(f"{v:.6g}")

    rod, cam = cfg.rod, cfg.camera
    out: dict[str, Any] = {}
    if rod.home_pose is None:
        out["rod.home_pose"] = [clean(v) for v in home_pose(rod)]
    if rod.dt is None:
        out["rod.dt"] = clean(time_step(rod))
    cx, cy = principal_point(cam)
    if cam.cx is None:
        out["camera.cx"] = clean(cx)
    if cam.cy is None:
        out["camera.cy"] = clean(cy)
    checkpoint = getattr(cfg.feature, "checkpoint", "")
    if checkpoint is None:
        out["feature.checkpoint"] = "the packaged rodctl/assets/encoder.npz"
    return out


@config_app.command("schema")
@user_errors
def config_schema(
    compare: Annotated[
        bool, typer.Option("--compare", help="The schema of `rodctl compare` configs instead.")
    ] = False,
    sweep: Annotated[
        bool, typer.Option("--sweep", help="The schema of `rodctl sweep` configs instead.")
    ] = False,
) -> None:
    """Print the JSON schema of the experiment config (or of compare / sweep configs)."""
    from rodctl.config.compare import CompareConfig
    from rodctl.config.sweep import SweepConfig

    if compare and sweep:
        raise UserError("--compare and --sweep: give one of them (a config is one or the other)")
    model = SweepConfig if sweep else CompareConfig if compare else ExperimentConfig
    typer.echo(json.dumps(model.model_json_schema(), indent=2))


OutOpt = Annotated[
    str,
    typer.Option(
        "--out", "-o", help="Parent folder of the run directory.", show_default=True, metavar="DIR"
    ),
]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or table.")]


JsonOpt = Annotated[
    bool,
    typer.Option(
        "--json",
        help="Print the summary as one JSON object on stdout (with `run_dir`) instead of "
        "the table and the run directory.",
    ),
]
LiveOpt = Annotated[
    bool,
    typer.Option(
        "--live",
        help="Stream the run to Foxglove (WebSocket, localhost); the run starts when a "
        "client subscribes. docs/reports.md.",
    ),
]
LivePortOpt = Annotated[
    int | None,
    typer.Option(
        "--live-port",
        help="Port of the --live server (0: any free one). [default: 8765]",
        show_default=False,
    ),
]
LiveRerunOpt = Annotated[
    str | None,
    typer.Option(
        "--live-rerun",
        metavar="URL",
        help="Also stream the run to a Rerun viewer already listening at URL, e.g. "
        "rerun+http://127.0.0.1:9876/proxy (start it with `rerun`). docs/reports.md.",
    ),
]


@app.command()
@user_errors
def simulate(
    config: ConfigArg,
    set_: SetOpt = None,
    out: OutOpt = "runs",
    quiet: QuietOpt = False,
    as_json: JsonOpt = False,
    live: LiveOpt = False,
    live_port: LivePortOpt = None,
    live_rerun: LiveRerunOpt = None,
) -> None:
    """Run one shape-servoing experiment; print the run directory as the last line.

    Exit code 0 when the run completed (converged or not: see summary.json), 1 when it
    failed (diverged, lost the rod, crashed) or was interrupted, 2 on bad input.

    Examples:

        rodctl simulate configs/default.yaml
        rodctl simulate configs/default.yaml --set run.max_steps=300 -o runs/mine
        rodctl simulate configs/default.yaml -q --json
    """
    from rodctl import timeline
    from rodctl.logs.sinks import start_helpers

    timeline.mark("main", "cli")
    live_port = _live_port(live, live_port)
    _experiment_config_only(config)
    cfg = load_config(config, set_ or [])
    # The figure and Rerun processes first: they import while this process imports the run's.
    with start_helpers(cfg.logging) as helpers:
        result = _simulate(cfg, out, quiet or as_json, live, live_port, live_rerun, helpers)
    if result.error:
        typer.echo(f"error: {result.error}", err=True)
    if as_json:
        from rodctl.runs import jsonable

        data = {**result.summary.to_json(), "run_dir": str(result.run.path)}
        typer.echo(json.dumps(jsonable(data), allow_nan=False))
    else:
        typer.echo(str(result.run.path))
    raise typer.Exit(code=result.exit_code)


def _simulate(
    cfg: ExperimentConfig,
    out: str,
    quiet: bool,
    live: bool,
    live_port: int,
    live_rerun: str | None,
    helpers: Any,
) -> Any:
    """`simulate`'s run, with its progress, its table and its live views (`helpers`: the
    started helper processes, `start_helpers`)."""
    from rodctl.records import RunSummary
    from rodctl.simulate import simulate as run_simulation

    table = not quiet
    rerun_view = _live_rerun(cfg, live_rerun) if live_rerun is not None else None
    view = _live_view(cfg, live_port) if live else None  # stopped when the run is over
    if table:  # rich (~0.05 s of CPU to import) only for the bar and the table
        from rodctl.display import print_summary, step_progress

        progress: Any = step_progress(cfg.run.max_steps)
    else:
        progress = nullcontext(None)
    with progress as on_step, view or nullcontext():

        def first_result(summary: RunSummary) -> None:
            # The table as soon as the episode has ended; the figures and meta.json follow.
            on_step.done()
            print_summary(summary)

        return run_simulation(
            cfg,
            out,
            argv=sys.argv,
            on_step=on_step,
            on_summary=first_result if table else None,
            live=[v for v in (view, rerun_view) if v is not None],
            helpers=helpers,
        )


def _live_port(live: bool, port: int | None) -> int:
    """`--live-port` (8765 when not given): only with --live, and a TCP port (0: any free)."""
    if port is None:
        return 8765
    if not live:
        raise UserError("--live-port is the port of the --live view: give --live too")
    if not 0 <= port <= 65535:
        raise UserError(f"--live-port {port}: a port is 0 to 65535 (0: any free one)")
    return port


def _experiment_config_only(config: str) -> None:
    """`simulate` runs an experiment config; a compare or sweep config is a `UserError` naming
    the command that runs it."""
    from rodctl.config import read_yaml  # the keys `_config_model` reads, without its models

    data = read_yaml(config)
    command = "sweep" if "parameters" in data else "compare" if "methods" in data else None
    if command is not None:
        raise UserError(
            f"{config}: this is a {command} config; run it with `rodctl {command} {config}`"
        )


def _live_rerun(cfg: ExperimentConfig, url: str) -> Any:
    """`simulate --live-rerun URL`: the run's Rerun recording, streamed to that viewer too."""
    from rodctl.logs.rerun import RerunSink, check_viewer

    if not url.strip():  # an unset shell variable, say: refused, not ignored
        raise UserError(
            "--live-rerun is empty: give the URL of a listening Rerun viewer, e.g. "
            "rerun+http://127.0.0.1:9876/proxy"
        )
    check_viewer(url)
    return RerunSink(None, cfg.logging, url=url)


def _live_view(cfg: ExperimentConfig, port: int) -> Any:
    """`simulate --live`: a started `LiveView` with a client subscribed (Ctrl-C: exit 1)."""
    from rodctl.logs.live import LiveView

    # A short grace at the end: the last messages are still on their way when the run ends.
    view = LiveView(cfg.logging, port=port, grace_s=0.5, arms=cfg.rod.arms).start()
    typer.echo(
        f"live view on {view.url}: in Foxglove, Open connection > Foxglove WebSocket > that URL; "
        "the run starts when it subscribes (Ctrl-C to give up)",
        err=True,
    )
    try:
        view.wait_for_client()
    except KeyboardInterrupt:
        view.stop()
        typer.echo("interrupted before the run started: no live client", err=True)
        raise typer.Exit(code=1) from None
    return view


VerifyOpt = Annotated[
    bool, typer.Option("--verify", help="Re-run the simulation and compare every step.")
]
RecoverOpt = Annotated[
    bool, typer.Option("--recover", help="Read an unfinished MCAP up to its last whole step.")
]
ReplayOutOpt = Annotated[
    str | None, typer.Option("--out", "-o", help="Write run.rrd and figures here instead.")
]
FiguresOpt = Annotated[bool, typer.Option("--figures/--no-figures", help="Redraw figures.")]
OpenOpt = Annotated[
    bool, typer.Option("--open", help="Open the rebuilt run.rrd in the Rerun viewer.")
]


def _nonnegative(value: float | None) -> float | None:
    """A finite number >= 0 (a tolerance): nan and inf are refused. Checked here, not by a
    range: typer's range check said "Input should be greater than or equal to 0" of nan."""
    if value is not None and not (math.isfinite(value) and value >= 0.0):
        raise typer.BadParameter(f"{value} is not a finite number >= 0")
    return value


def _positive(value: float | None) -> float | None:
    """A finite number > 0 (a rate)."""
    if value is not None and not (math.isfinite(value) and value > 0.0):
        raise typer.BadParameter(f"{value} is not a positive finite number")
    return value


ToleranceOpt = Annotated[
    float | None,
    typer.Option(
        "--tolerance",
        callback=_nonnegative,
        help="With --verify, accept numbers that differ by at most TOL * max(1, |value|) "
        "(a rerun on another CPU or BLAS kernel). 0 = bit for bit. [default: 0]",
        show_default=False,
        metavar="TOL",
    ),
]
ReplayQuietOpt = Annotated[
    bool, typer.Option("--quiet", "-q", help="No summary table: only the verdict and errors.")
]


@app.command()
@user_errors
def replay(
    path: Annotated[str, typer.Argument(help="A run directory or its run.mcap.")],
    verify: VerifyOpt = False,
    recover: RecoverOpt = False,
    out: ReplayOutOpt = None,
    figures: FiguresOpt = True,
    open_viewer: OpenOpt = False,
    tolerance: ToleranceOpt = None,
    quiet: ReplayQuietOpt = False,
) -> None:
    """Rebuild run.rrd and the figures from a run's MCAP alone and print its summary.

    With --verify, also re-run the simulation from the embedded config and compare every
    logged step: bit-identical, identical within --tolerance (the largest deviation per field
    and the two numeric environments are shown), or a mismatch (the first step and field;
    exit 1). Prints the output folder last.

    Examples:

        rodctl replay runs/20261201-120000_default --verify
        rodctl replay runs/20261201-120000_default/run.mcap --recover -q
    """
    from rodctl.replay import check_verifiable, format_summary, rebuild

    if tolerance is not None and not verify:
        raise UserError("--tolerance is how closely --verify's rerun must match: give --verify too")
    check = check_verifiable if verify else None  # refused before anything is written
    result = rebuild(path, out, recover=recover, figures=figures, check=check)
    if not quiet:
        typer.echo(format_summary(result.run), err=True)
        for note in result.notes:
            typer.echo(f"note: {note}", err=True)
    code = 0
    if not result.run.records and not result.run.complete:
        # A killed run cut before its first flush: nothing came back.
        typer.echo(
            f"error: {path}: the log holds no complete step (the run was cut before its first "
            "steps were flushed: logging.flush_every_steps); run.rrd holds its header only",
            err=True,
        )
        code = 1
    elif verify:
        code = _verify(result.run, tolerance or 0.0)
    if open_viewer:
        _open_rerun(result.rrd)
    typer.echo(str(result.rrd.parent if result.rrd else result.run.path.parent))
    raise typer.Exit(code=code)


def _verify(run: Any, tolerance: float) -> int:
    """`replay --verify`: rerun the log's steps and say the verdict, the folder's config.yaml
    checked against the log too; the exit code (1: a mismatch or an edited config.yaml)."""
    from rodctl.replay import config_file_differences
    from rodctl.replay import verify as verify_run

    edited = config_file_differences(run)
    for diff in edited:
        typer.echo(f"verify: config.yaml differs from the log: {diff}", err=True)
    verdict = verify_run(run, tolerance=tolerance)
    for line in verdict.report():
        typer.echo(line, err=True)
    if edited:  # the log reproduces, the folder's config.yaml does not say what ran
        typer.echo(
            "verify: FAILED: the log's steps rerun as above, but the run folder's config.yaml "
            f"was edited ({len(edited)} key(s) above)",
            err=True,
        )
        return 1
    return verdict.exit_code


def _open_rerun(rrd) -> None:
    """Launch the Rerun viewer on `rrd` when a viewer and a display are available."""
    import os
    import shutil
    import subprocess

    exe = shutil.which("rerun")
    if exe is None or not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        typer.echo(
            f"note: no Rerun viewer or display here; open the file with `rerun {rrd}` on a desktop",
            err=True,
        )
        return
    subprocess.Popen([exe, str(rrd)], start_new_session=True)


_DatasetOpt = Annotated[
    str | None,
    typer.Option(
        "--dataset",
        help="Train on a dataset.npz from an earlier run, or a run folder (a recording).",
    ),
]
_QuickOpt = Annotated[
    bool,
    typer.Option(
        "--quick",
        help="A quick encoder: 3,000 samples, 300 epochs, batches of 500 (about 30 s on "
        "2 cores), enough for a new rod or camera. A --set of one of these sizes wins.",
    ),
]


def _training_recording(cfg: ExperimentConfig, dataset: str | None) -> tuple[ExperimentConfig, Any]:
    """--dataset: a recording's run folder (its points count goes into `cfg`), or a file."""
    from pathlib import Path

    from rodctl.recordings.dataset import is_run

    recording = None
    if dataset is not None and is_run(dataset):  # a recording's run folder (docs/recordings.md)
        from rodctl.recordings.dataset import run_dataset, with_points

        recording = run_dataset(dataset)
        cfg = with_points(cfg, recording.centerlines.shape[1])
    elif dataset is not None and Path(dataset).is_dir():
        raise UserError(
            f"--dataset {dataset}: a folder that is not a run folder (no run.mcap); give a run "
            "folder or a dataset .npz"
        )
    elif dataset is not None and not Path(dataset).is_file():
        what = "not a regular file" if Path(dataset).exists() else "no such file"
        raise UserError(f"--dataset {dataset}: {what} (give a dataset .npz or a run folder)")
    return cfg, recording


def _train_in_run(cfg: ExperimentConfig, run: Any, dataset: str | None, quiet: bool) -> dict:
    """Train the encoder in `run` and finish the run: completed, interrupted (exit 1), failed."""
    from pathlib import Path

    from rodctl.training.encoder import train_encoder as train

    try:
        with sigterm_as_interrupt():
            metrics = train(
                cfg, run, dataset=Path(dataset) if dataset else None, progress=not quiet
            )
    except KeyboardInterrupt:
        run.finish("interrupted", error="interrupted by a signal (SIGINT or SIGTERM)")
        typer.echo(f"error: interrupted; what was written is in {run.path}", err=True)
        typer.echo(str(run.path))
        raise typer.Exit(code=1) from None
    except UserError as exc:
        # Bad input found once the folder existed (a file that is not a dataset): if nothing
        # was written yet, nothing is left behind.
        if not run.discard_if_empty():
            run.finish("failed", error=str(exc))
        raise
    except BaseException as exc:
        run.finish("failed", error=f"{type(exc).__name__}: {exc}")
        raise
    run.finish("completed")
    return metrics


@app.command("train-encoder")
@user_errors
def train_encoder(
    config: ConfigArg,
    set_: SetOpt = None,
    out: OutOpt = "runs",
    dataset: _DatasetOpt = None,
    quick: _QuickOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Collect rod centerlines through the camera and train the autoencoder feature.

    Writes dataset.npz, encoder.npz and encoder.pt (the same weights, normalisation, config
    and metrics, for numpy and for torch) and metrics.json into a new run directory; prints it
    as the last line. Use the checkpoint with --set feature.checkpoint=RUN_DIR/encoder.npz.
    --dataset also takes a recording's run folder (`rodctl import`; docs/recordings.md).
    Needs torch: pip install -e ".[train]" (docs/install.md).

    Examples:

        rodctl train-encoder configs/default.yaml --quick
        rodctl train-encoder configs/default.yaml --dataset runs/20261201-120000_default/dataset.npz
    """
    from rodctl.features.autoencoder import require_torch
    from rodctl.runs import RunDir
    from rodctl.training.encoder import quick_overrides

    require_torch("rodctl train-encoder")  # before anything is collected or written
    cfg = load_config(config, set_ or [])
    if quick:  # the quick sizes, after the --sets (a feature.type=… among them included)
        keep = frozenset(item.partition("=")[0].strip() for item in set_ or [])
        cfg = load_config(config, [*(set_ or []), *quick_overrides(cfg, keep)])
    cfg, recording = _training_recording(cfg, dataset)
    run = RunDir.create(out, cfg, command="train-encoder", argv=sys.argv)
    if recording is not None:
        from rodctl.recordings.dataset import write_run_dataset

        try:
            dataset = str(write_run_dataset(recording, cfg, run.path / "dataset.npz"))
        except UserError:
            run.discard_if_empty()
            raise
    metrics = _train_in_run(cfg, run, dataset, quiet)
    if not quiet:
        keys = [k for k in metrics if "px" in k or k.endswith("_s")]
        for k in keys:
            typer.echo(f"{k}: {metrics[k]}", err=True)
    typer.echo(str(run.path))


@app.command("train-model")
@user_errors
def train_model(
    config: Annotated[
        str,
        typer.Argument(
            help="Experiment config whose estimator is `learned`, e.g. configs/yu2023.yaml."
        ),
    ],
    set_: SetOpt = None,
    out: OutOpt = "runs",
    quiet: QuietOpt = False,
) -> None:
    """Collect random-motion data in the simulator and train the learned Jacobian model.

    The config's estimator must be `learned` (its `data` and `training` sections say how).
    Writes model.npz (numpy arrays + JSON, no pickles) and metrics.json (one-step prediction
    errors, the set-up fingerprint, the model's sha256) into a new run directory and prints it
    as the last line. Use it with --set estimator.checkpoint=RUN_DIR/model.npz.
    """
    from rodctl.runs import RunDir
    from rodctl.training.learned import train_model as train

    try:  # the model to be trained replaces any the config names (it is not checked)
        cfg = load_config(config, [*(set_ or []), "estimator.checkpoint=null"])
    except UserError:
        cfg = load_config(config, set_ or [])  # its own error, or not a learned estimator
    if cfg.estimator.type != "learned":
        raise UserError(
            f"{config}: train-model trains the learned Jacobian, but estimator.type is "
            f"{cfg.estimator.type!r}; set estimator.type=learned"
        )
    run = RunDir.create(out, cfg, command="train-model", argv=sys.argv)
    try:
        with sigterm_as_interrupt():
            metrics = train(cfg, run, progress=not quiet)
    except KeyboardInterrupt:
        run.finish("interrupted", error="interrupted by a signal (SIGINT or SIGTERM)")
        typer.echo(f"error: interrupted; what was written is in {run.path}", err=True)
        typer.echo(str(run.path))
        raise typer.Exit(code=1) from None
    except BaseException as exc:
        run.finish("failed", error=f"{type(exc).__name__}: {exc}")
        raise
    run.finish("completed")
    if not quiet:
        for part in ("train", "validation"):
            if metrics.get(part):
                err = metrics[part]
                typer.echo(
                    f"{part}: one-step error {err['mean_error']:.4g} "
                    f"({100 * err['relative_error']:.1f} % of |ds|)",
                    err=True,
                )
        typer.echo(f"sha256: {metrics['sha256']}", err=True)
    typer.echo(str(run.path))


ExecutorOpt = Annotated[
    str,
    typer.Option(
        "--executor",
        help="Where episodes run: 'local' (this machine: in-process for 1 worker, else a "
        "process pool), 'ray' (a local Ray started for the run, or --address), or a plug-in's "
        "(`rodctl plugins`).",
    ),
]
AddressOpt = Annotated[
    str | None,
    typer.Option(
        "--address",
        help="An existing Ray cluster (HOST:PORT or 'auto'); needs --executor ray.",
    ),
]
ResumeOpt = Annotated[
    str | None,
    typer.Option(
        "--resume",
        help="Finish an interrupted run in its folder: its finished episodes are kept (the "
        "config must be the same; workers and executor may differ).",
        metavar="RUN_DIR",
    ),
]


def _given_on_command_line(ctx: typer.Context) -> set[str]:
    """The parameters of `ctx`'s command the user gave on the command line (not defaults).
    typer carries its own click: its ParameterSource is compared by name."""
    return {
        n for n in ctx.params if getattr(ctx.get_parameter_source(n), "name", "") == "COMMANDLINE"
    }


def _finish_batch(
    ctx: typer.Context, runner: Callable[..., Any], config: str, **kwargs: Any
) -> None:
    """Run compare/sweep (`runner(config, overrides, out, ...)`); an interrupted run prints its
    folder and exits 1 (results kept)."""
    from rodctl.bench.runner import RunInterrupted

    resume = kwargs["resume"]
    same_parent = resume and Path(kwargs["out"]).resolve() == Path(resume).resolve().parent
    if resume and "out" in _given_on_command_line(ctx) and not same_parent:
        # the first run's command with --resume added gives its own -o: that one is fine
        raise UserError(
            f"--resume continues {kwargs['resume']} in its own folder; -o/--out "
            f"({kwargs['out']}) does not apply to it: leave it out"
        )
    kwargs["overrides"] = kwargs.pop("set_") or []
    kwargs["progress"] = not kwargs.pop("quiet")
    try:
        # Outside the episodes and the reports (set-up, an encoder trained for 'auto', between
        # a suite's scenarios) SIGTERM ends the run as Ctrl-C does, recorded as interrupted.
        with sigterm_as_interrupt():
            folder = runner(config, **kwargs)
    except RunInterrupted as exc:
        kept = "partial results kept" if exc.done else "no episode had finished"
        typer.echo(f"error: {exc}; {kept}, resume with --resume", err=True)
        typer.echo(str(exc.folder))
        raise typer.Exit(code=1) from None
    typer.echo(str(folder))


WorkersOpt = Annotated[
    int | None,
    typer.Option(
        "--workers",
        min=1,
        help="Worker processes, or CPUs of a Ray started for the run (default: the config's).",
    ),
]


@app.command()
@user_errors
def compare(
    ctx: typer.Context,
    config: Annotated[str, typer.Argument(help="Compare config, e.g. configs/compare.yaml.")],
    set_: SetOpt = None,
    out: OutOpt = "runs",
    workers: WorkersOpt = None,
    executor: ExecutorOpt = "local",
    address: AddressOpt = None,
    resume: ResumeOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Benchmark several methods on one shared set of reachable targets.

    Every method gets the same start, targets, speed limits, step and probing budgets and
    success criterion. Writes results.jsonl (as episodes finish), results.csv/json, summary.md
    and figures/ into a new folder and prints it as the last line. SIGINT/SIGTERM stop it
    within seconds, keeping every finished episode (exit 1).

    Examples:

        rodctl compare configs/compare-smoke.yaml
        rodctl compare configs/compare.yaml --workers 2 --set targets.count=10
        rodctl compare configs/compare.yaml --resume runs/20261201-120000_compare
    """
    from rodctl.bench.compare import run_compare
    from rodctl.bench.suite import run_suite
    from rodctl.config import read_yaml

    data = read_yaml(config)
    if not {"scenarios", "methods", "parameters"} & set(data):
        raise UserError(
            f"{config}: this is an experiment config (no `methods`); run it with "
            f"`rodctl simulate {config}`, or compare methods with a compare config such as "
            "configs/compare.yaml"
        )
    if "parameters" in data:
        raise UserError(f"{config}: this is a sweep config; run it with `rodctl sweep {config}`")
    # A config with `scenarios` is a benchmark suite: every scenario is a compare of its own (a
    # compare folder's resolved config.yaml says `scenarios: null`: a plain compare).
    runner = run_suite if data.get("scenarios") is not None else run_compare
    _finish_batch(
        ctx, runner, config, set_=set_, out=out, quiet=quiet, workers=workers,
        executor=executor, address=address, resume=resume,
    )  # fmt: skip


@app.command()
@user_errors
def sweep(
    ctx: typer.Context,
    config: Annotated[str, typer.Argument(help="Sweep config, e.g. configs/sweep-tuning.yaml.")],
    set_: SetOpt = None,
    out: OutOpt = "runs",
    workers: WorkersOpt = None,
    executor: ExecutorOpt = "local",
    address: AddressOpt = None,
    resume: ResumeOpt = None,
    quiet: QuietOpt = False,
) -> None:
    """Sweep config values (a grid or a seeded random search) over seeds, targets and methods.

    Writes results.jsonl (as episodes finish), results.csv (a column per swept key),
    summary.md / summary.json ranked by the config's metric, and a figure of the metric
    against each swept key; prints the folder as the last line.

    Examples:

        rodctl sweep configs/sweep-smoke.yaml
        rodctl sweep configs/sweep-tuning.yaml --workers 2
    """
    from rodctl.bench.sweep import run_sweep
    from rodctl.config import read_yaml

    data = read_yaml(config)
    if "parameters" not in data:
        if {"scenarios", "methods"} & set(data):
            raise UserError(
                f"{config}: this is a compare config (no `parameters`); run it with "
                f"`rodctl compare {config}`"
            )
        raise UserError(
            f"{config}: this is an experiment config (no `parameters`); run it with "
            f"`rodctl simulate {config}`, or sweep its keys with a sweep config such as "
            "configs/sweep-smoke.yaml"
        )
    _finish_batch(
        ctx, run_sweep, config, set_=set_, out=out, quiet=quiet, workers=workers,
        executor=executor, address=address, resume=resume,
    )  # fmt: skip


_EstimatePathArg = Annotated[
    str, typer.Argument(help="A run directory, its run.mcap, or a points recording (.csv/.npz).")
]
_EstimatorOpt = Annotated[
    list[str] | None,
    typer.Option("--estimator", "-e", help="Registered estimator to run (repeat); default all."),
]
_FeatureOpt = Annotated[
    str,
    typer.Option(
        "--feature",
        help="Feature space: logged (a run's own s), points, or a registered feature type "
        "(bezier, fourier, ...). Default: logged for a run, points for a recording.",
    ),
]
_InitOpt = Annotated[
    int | None,
    typer.Option("--init", min=1, help="Recording pairs J_0 is fitted from (default 10 q)."),
]
_ScaledOpt = Annotated[
    bool,
    typer.Option(
        "--scaled/--defaults",
        help="Dead zones, Broyden's step and the ridge scaled to the data's motion and noise "
        "(docs/recordings.md), or every estimator's config defaults.",
    ),
]
_EstimateOutOpt = Annotated[
    str | None, typer.Option("--out", "-o", help="Folder for results.csv and steps.csv.")
]
_PlotsOpt = Annotated[
    bool, typer.Option("--plots/--no-plots", help="Write errors.png and medians.png (matplotlib).")
]
_CheckpointOpt = Annotated[
    str | None,
    typer.Option("--checkpoint", help="--feature autoencoder: the encoder.npz (train-encoder's)."),
]
_ForceOpt = Annotated[
    bool,
    typer.Option("--force", help="Overwrite the results of an earlier estimate in the folder."),
]


def _estimate_folder(src: Any, recording: bool, out: str | None, force: bool) -> tuple[Any, list]:
    """The results folder and the earlier estimate's files in it (refused without --force)."""

    from rodctl import estimate as est

    if out is not None:
        dest = out_path(out)
    elif recording:
        dest = src.with_name(src.stem + "-estimate")
    else:
        dest = (src if src.is_dir() else src.parent) / "estimate"
    if out is None and not force:
        dest = est.free_folder(dest)  # a second estimate: estimate-2/, never over the first
    earlier = [p.name for p in est.result_files(dest) if p.exists()]
    if earlier and not force:
        raise UserError(
            f"--out {dest}: holds an earlier estimate ({', '.join(earlier)}); "
            "choose another folder, or overwrite it with --force"
        )
    return dest, earlier


def _estimate_pairs(
    src: Any, recording: bool, feature: str, init: int | None, checkpoint: str | None
) -> Any:
    """The (Delta s, Delta r) pairs of a points recording or of a run's log."""
    from rodctl import estimate as est

    if checkpoint is not None and (feature or ("points" if recording else "logged")) in (
        "points",
        "logged",
    ):  # it would be ignored (the rule of docs/reliability.md)
        raise UserError("--checkpoint is for a learned feature: give --feature autoencoder too")
    if recording:
        from rodctl.recordings.points import read_points

        return est.pairs_from_recording(
            read_points(src),
            init=init,
            feature=feature or "points",
            checkpoint=checkpoint,
            source=str(src),
        )
    from rodctl.replay import read_run

    run = read_run(src, images=False)
    return est.pairs_from_run(run, feature=feature or "logged", init=init, checkpoint=checkpoint)


def _write_estimate(result: Any, dest: Any, earlier: list, plots: bool) -> None:
    """Write results.csv, steps.csv (and the plots) into `dest`; print the table and notes."""
    from rodctl import estimate as est

    make_out_folder(dest)
    try:
        for stale in est.result_files(dest) if earlier else ():
            stale.unlink(missing_ok=True)  # --force: no plot of the earlier estimate left beside
        est.write_results(result, dest)
        if plots:
            est.write_plots(result, dest)
    except OSError as exc:  # a full or read-only disk: exit 1 (docs/reliability.md)
        raise out_error("--out", dest, "cannot write the results", exc) from None
    typer.echo(est.format_table(result), err=True)
    for r in result.runs:
        if r.outcome not in ("completed",) and r.note:
            typer.echo(f"{r.name}: {r.outcome}: {r.note}", err=True)


@app.command()
@user_errors
def estimate(
    path: _EstimatePathArg,
    estimator: _EstimatorOpt = None,
    feature: _FeatureOpt = "",
    init: _InitOpt = None,
    scaled: _ScaledOpt = False,
    out: _EstimateOutOpt = None,
    plots: _PlotsOpt = True,
    checkpoint: _CheckpointOpt = None,
    force: _ForceOpt = False,
) -> None:
    """Run the online Jacobian estimators over a recorded (Delta s, Delta r), offline.

    Reports each estimator's one-step-ahead prediction error of Delta s against the
    zero-motion predictor and a least-squares J fitted in hindsight; writes results.csv,
    steps.csv and the plots errors.png, medians.png (default: RUN_DIR/estimate, or beside the
    recording) and prints the folder last.
    """
    from pathlib import Path

    from rodctl import estimate as est

    src = Path(path)
    recording = src.suffix.lower() in (".csv", ".npz")
    dest, earlier = _estimate_folder(src, recording, out, force)
    pairs = _estimate_pairs(src, recording, feature, init, checkpoint)
    result = est.estimate(pairs, estimator or None, scaled=scaled)
    _write_estimate(result, dest, earlier, plots)
    typer.echo(str(dest))


def _print_import(run_dir: Any, notes: list[str]) -> None:
    """An import's notes on stderr, then its run folder as the last line of stdout."""
    for note in notes:
        typer.echo(f"note: {note}", err=True)
    typer.echo(str(run_dir))


def _numbers(flag: str, text: str | None, n: int, kind: type) -> list:
    """`--flag 1,2,3`: `n` comma-separated values of `kind`, or a UserError naming the flag."""
    try:
        vals = [kind(v) for v in (text or "").split(",")]
    except ValueError:
        vals = []
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise UserError(f"{flag} {text}: give {n} comma-separated finite numbers")
    return vals


#: OpenCV's 8-bit HSV bounds: hue 0-180 (degrees / 2; pixels reach 179), saturation and value 0-255.
_HSV_MAX = (180, 255, 255)


def _hsv(flag: str, text: str) -> list[int]:
    """`--hsv-low/--hsv-high H,S,V` in OpenCV's 8-bit ranges, or a UserError naming the flag
    (out of range, no pixel could match: the import would blame every frame instead)."""
    vals = _numbers(flag, text, 3, int)
    for name, v, top in zip(("H", "S", "V"), vals, _HSV_MAX, strict=True):
        if not 0 <= v <= top:
            raise UserError(f"{flag} {text}: {name} = {v} is outside 0-{top} (OpenCV's 8-bit HSV)")
    return vals


_NO_MASK = "--mask-topic: masks are read from a ROS 2 bag beside its --image-topic"

_RecordingArg = Annotated[
    str, typer.Argument(help="A points recording (.csv/.npz), a ROS 2 bag or an image folder.")
]
_ImportNameOpt = Annotated[
    str | None, typer.Option("--name", help="Run name (default: import- and the file's stem).")
]
_PointsTopicOpt = Annotated[
    str | None,
    typer.Option("--points-topic", help="Bag: the tracked points (MarkerArray, Path, ...)."),
]
_PoseTopicOpt = Annotated[
    list[str] | None,
    typer.Option("--pose-topic", help="Bag: an end effector's PoseStamped (once or twice)."),
]
_ToleranceOpt = Annotated[
    float,
    typer.Option(
        "--tolerance",
        callback=_nonnegative,
        help="Bag, image folder or video: largest pose gap (s) around a frame.",
    ),
]
_ImageTopicOpt = Annotated[
    str | None,
    typer.Option("--image-topic", help="Bag: camera frames (Image or CompressedImage)."),
]
_CameraInfoTopicOpt = Annotated[
    str | None, typer.Option("--camera-info-topic", help="Bag: CameraInfo (K, D).")
]
_CameraOpt = Annotated[
    str | None,
    typer.Option("--camera", help="Images: YAML with the camera's pose and extraction settings."),
]
_ClampPoseOpt = Annotated[
    str | None, typer.Option("--clamp-pose", help="Images: the fixed end's X,Y,THETA (world).")
]
_HsvLowOpt = Annotated[str, typer.Option("--hsv-low", help="Images: rod colour H,S,V low.")]
_HsvHighOpt = Annotated[str, typer.Option("--hsv-high", help="Images: rod colour H,S,V high.")]
_PosesOpt = Annotated[
    str | None,
    typer.Option("--poses", help="Image folder or video: CSV of gripper poses t,x,y,theta."),
]
_TopicsOpt = Annotated[
    str | None,
    typer.Option("--topics", help="Bag: YAML mapping of its topics (flags replace keys)."),
]
_TfFrameOpt = Annotated[
    list[str] | None,
    typer.Option("--tf-frame", help="Bag: an end effector's tf child frame (once or twice)."),
]
_TfTopicOpt = Annotated[
    str | None, typer.Option("--tf-topic", help="Bag: the TFMessage topic (default /tf).")
]
_CalibrationOpt = Annotated[
    str | None,
    typer.Option("--calibration", help="Images: YAML with an extrinsic or marked points."),
]
_ExtrinsicOpt = Annotated[
    str | None,
    typer.Option("--extrinsic", help="Images: world->camera RX,RY,RZ,TX,TY,TZ (Rodrigues)."),
]
_FpsOpt = Annotated[
    float | None,
    typer.Option("--fps", callback=_positive, help="Video: frame rate (t = k / fps)."),
]
_FrameTimesOpt = Annotated[
    str | None, typer.Option("--frame-times", help="Video: CSV with each frame's t.")
]
_MaskTopicOpt = Annotated[
    str | None,
    typer.Option("--mask-topic", help="Bag: mono8/8UC1 rod masks, used instead of HSV."),
]
_TfWorldOpt = Annotated[
    str | None,
    typer.Option("--tf-world", help="Bag: compose tf chains up to this frame (default root)."),
]


def _import_calibration(calibration: str | None, extrinsic: str | None) -> Any:
    """The camera calibration from `--calibration FILE` or `--extrinsic`, or None (not both)."""
    if calibration and extrinsic:
        raise UserError("--calibration and --extrinsic: give one of them")
    if calibration:
        from rodctl.recordings.calibration import load_calibration

        return load_calibration(calibration)
    if extrinsic:
        from rodctl.recordings.calibration import extrinsic_from_flag

        return extrinsic_from_flag(_numbers("--extrinsic", extrinsic, 6, float))
    return None


def _frames_args(
    path: str,
    camera: str | None,
    clamp_pose: str | None,
    hsv_low: str,
    hsv_high: str,
    tolerance: float,
    name: str | None,
    calibration: Any,
) -> dict:
    """The keyword arguments every camera-frames import takes (needs --camera);
    `calibration`: --calibration / --extrinsic as read (`_import_calibration`)."""
    if not camera:
        raise UserError(f"{path}: camera frames need --camera FILE (intrinsics, pose)")
    clamp = None if clamp_pose is None else _numbers("--clamp-pose", clamp_pose, 3, float)
    return dict(
        camera=camera, clamp_pose=clamp,
        hsv_low=_hsv("--hsv-low", hsv_low),
        hsv_high=_hsv("--hsv-high", hsv_high),
        tolerance=tolerance, name=name, calibration=calibration,
    )  # fmt: skip


_BAG_ONLY = (
    "points_topic", "pose_topic", "image_topic", "camera_info_topic", "topics", "tf_frame",
    "tf_topic", "tf_world",
)  # fmt: skip


def _refuse_misplaced_flags(
    path: str, is_dir: bool, is_video: bool, poses: str | None, flags: dict[str, Any]
) -> None:
    """A UserError for --mask-topic or a bag-only flag (in `flags`) given with another input."""
    if flags["mask_topic"] and (is_video or poses):
        raise UserError(_NO_MASK)
    misplaced = ["--" + key.replace("_", "-") for key in _BAG_ONLY if flags[key]]
    if misplaced and not (is_dir and not poses):
        kind = "an image folder with --poses" if is_dir else "not a ROS 2 bag"
        raise UserError(
            f"{', '.join(misplaced)}: topics are read from a ROS 2 bag; {path} is {kind}"
        )


def _refuse_misplaced_timing(
    path: str, is_video: bool, fps: float | None, frame_times: str | None
) -> None:
    """A UserError for --fps or --frame-times with another input than a video, or both."""
    timing = [f for f, v in (("--fps", fps), ("--frame-times", frame_times)) if v is not None]
    if timing and not is_video:
        raise UserError(f"{', '.join(timing)}: frame times of a video; {path} is not one")
    if len(timing) == 2:
        raise UserError("--fps and --frame-times: give one of them (the frame times)")


def _refuse_empty(flags: dict[str, Any]) -> None:
    """A topic, frame or file option given as "" (an unset shell variable) is refused by name,
    whatever the input: it is no topic, not a wildcard."""
    for key, value in flags.items():
        values = value if isinstance(value, list) else [value]
        if any(v is not None and not str(v).strip() for v in values):
            flag = "--" + key.replace("_", "-")
            what = "a file" if key == "topics" else "a name (e.g. --pose-topic /arm/pose)"
            raise UserError(f"{flag} is empty: give {what}")


def _bag_topics(flags: dict[str, Any]) -> dict[str, Any]:
    """The bag's topics: the flags, each unset one from the --topics YAML, checked together."""
    t = dict(flags)
    mapping = None
    if t["topics"]:
        from rodctl.recordings.mapping import load_mapping

        mapping = load_mapping(t["topics"])
    if mapping is not None:
        t["image_topic"] = t["image_topic"] or mapping.image
        t["camera_info_topic"] = t["camera_info_topic"] or mapping.camera_info
        t["points_topic"] = t["points_topic"] or (None if t["image_topic"] else mapping.points)
        t["pose_topic"] = t["pose_topic"] or mapping.poses or None
        t["mask_topic"] = t["mask_topic"] or mapping.mask
        if mapping.tf is not None:
            t["tf_frame"] = t["tf_frame"] or mapping.tf.frames
            t["tf_topic"] = t["tf_topic"] or mapping.tf.topic
            t["tf_world"] = t["tf_world"] or mapping.tf.world
    t["tf_topic"] = t["tf_topic"] or "/tf"
    if t["image_topic"] and t["points_topic"]:
        raise UserError(
            "--image-topic and --points-topic (or the --topics keys image and points): a bag "
            "import reads camera frames or tracked points, not both"
        )
    if t["mask_topic"] and not t["image_topic"]:
        raise UserError(_NO_MASK)
    for flag, key, entry in (
        ("--pose-topic", "pose_topic", "poses"),
        ("--tf-frame", "tf_frame", "tf.frames"),
    ):
        named = list(t[key] or [])
        if len(set(named)) < len(named):
            # named as the user gave it: the flags, or the --topics file's key
            where = flag if flags[key] else f"{t['topics']}: {entry}"
            raise UserError(f"{where} {' '.join(named)}: each end's own; one is given twice")
    if t["tf_world"] and not t["tf_frame"]:
        raise UserError("--tf-world: goes with --tf-frame (the tf chains it ends)")
    return t


def _import_video(
    path: str, out: str, poses: str | None, fps: float | None, frame_times: str | None,
    frames_args: Callable[[], dict],
) -> None:  # fmt: skip
    """Import the video at `path` with its --poses CSV; print the run folder."""
    from rodctl.recordings.importer import import_video

    if not poses:
        raise UserError(f"{path}: a video needs --poses CSV (t,x,y,theta of the gripper)")
    run_dir, notes = import_video(
        path, out, poses=poses, fps=fps, frame_times=frame_times, **frames_args()
    )
    _print_import(run_dir, notes)


def _import_bag_folder(
    path: str, out: str, t: dict[str, Any], tolerance: float, name: str | None,
    frames_args: Callable[[], dict],
) -> None:  # fmt: skip
    """Import the ROS 2 bag at `path` (camera frames or tracked points, topics `t`); print it."""
    from rodctl.recordings.importer import import_bag, import_bag_images

    ends = len(t["pose_topic"] or []) + len(t["tf_frame"] or [])
    if t["image_topic"]:
        run_dir, notes = import_bag_images(
            path, out, image_topic=t["image_topic"], info_topic=t["camera_info_topic"],
            pose_topic=t["pose_topic"] or [], tf_frame=t["tf_frame"] or [],
            tf_topic=t["tf_topic"], tf_world=t["tf_world"], mask_topic=t["mask_topic"],
            **frames_args(),
        )  # fmt: skip
        _print_import(run_dir, notes)
        return
    if not t["points_topic"] or not ends:
        raise UserError(
            f"{path}: a folder is a ROS 2 bag (give --points-topic or --image-topic, and "
            "--pose-topic or --tf-frame, or --topics YAML) or an image folder (give --poses "
            "CSV and --camera FILE)"
        )
    run_dir, notes = import_bag(
        path, out, t["points_topic"], t["pose_topic"] or [], tolerance=tolerance, name=name,
        tf_frames=t["tf_frame"] or [], tf_topic=t["tf_topic"], tf_world=t["tf_world"],
    )  # fmt: skip
    _print_import(run_dir, notes)


#: `import` options that apply to some inputs only, and to which: a tracked-points input has no
#: camera frames, so these are refused there, not ignored.
_FRAMES = "camera frames (a video, an image folder, an image bag)"
_ONLY_FOR = {
    "camera": _FRAMES, "clamp_pose": _FRAMES, "hsv_low": _FRAMES, "hsv_high": _FRAMES,
    "calibration": _FRAMES, "extrinsic": _FRAMES,
    "poses": "an image folder or a video",
    "tolerance": "inputs whose poses are matched to frames by time (a bag, an image folder, "
    "a video)",
}  # fmt: skip


def _refuse_options(given: set[str], path: str, what: str, names: tuple[str, ...]) -> None:
    """A UserError naming the options of `names` in `given` and the inputs they apply to."""
    groups: dict[str, list[str]] = {}  # where they apply -> the options given
    for n in names:
        if n in given:
            groups.setdefault(_ONLY_FOR[n], []).append("--" + n.replace("_", "-"))
    if groups:
        said = "; ".join(
            f"{', '.join(flags)} {'apply' if len(flags) > 1 else 'applies'} to {where}"
            for where, flags in groups.items()
        )
        raise UserError(f"{said}; {path} is {what}")


@app.command("import")
@user_errors
def import_recording(
    ctx: typer.Context,
    path: _RecordingArg,
    out: OutOpt = "runs",
    name: _ImportNameOpt = None,
    points_topic: _PointsTopicOpt = None,
    pose_topic: _PoseTopicOpt = None,
    tolerance: _ToleranceOpt = 0.2,
    image_topic: _ImageTopicOpt = None,
    camera_info_topic: _CameraInfoTopicOpt = None,
    camera: _CameraOpt = None,
    clamp_pose: _ClampPoseOpt = None,
    hsv_low: _HsvLowOpt = "170,120,50",
    hsv_high: _HsvHighOpt = "10,255,255",
    poses: _PosesOpt = None,
    topics: _TopicsOpt = None,
    tf_frame: _TfFrameOpt = None,
    tf_topic: _TfTopicOpt = None,
    calibration: _CalibrationOpt = None,
    extrinsic: _ExtrinsicOpt = None,
    fps: _FpsOpt = None,
    frame_times: _FrameTimesOpt = None,
    mask_topic: _MaskTopicOpt = None,
    tf_world: _TfWorldOpt = None,
) -> None:
    """Turn a recording into a rodctl run folder (config.yaml, meta.json, summary.json,
    run.mcap with the contract topics) that replay, Foxglove and estimate read.

    Reads the points format (per-frame tracked points plus one or two end-effector poses), a
    ROS 2 bag (tracked points or camera frames, with PoseStamped or tf poses; topics by flags
    or --topics YAML), an image folder or a video with a CSV of poses (docs/recordings.md).
    Prints the run directory last; exit 2 on a bad file or --name, 1 when cut short."""
    from pathlib import Path

    from rodctl.recordings.importer import import_image_folder, run_name
    from rodctl.recordings.video import VIDEO_SUFFIXES

    run_name(name, path)  # a bad --name is refused before any work
    is_dir, is_video = Path(path).is_dir(), Path(path).suffix.lower() in VIDEO_SUFFIXES
    # Read first where frames may follow; a points file refuses the options by name instead.
    calib = _import_calibration(calibration, extrinsic) if is_dir or is_video else None
    frames_args = functools.partial(
        _frames_args, path, camera, clamp_pose, hsv_low, hsv_high, tolerance, name, calib
    )
    flags = dict(
        points_topic=points_topic, pose_topic=pose_topic, image_topic=image_topic,
        camera_info_topic=camera_info_topic, topics=topics, tf_frame=tf_frame,
        tf_topic=tf_topic, tf_world=tf_world, mask_topic=mask_topic,
    )  # fmt: skip
    _refuse_empty(flags)
    _refuse_misplaced_flags(path, is_dir, is_video, poses, flags)
    _refuse_misplaced_timing(path, is_video, fps, frame_times)
    if is_video:
        _import_video(path, out, poses, fps, frame_times, frames_args)
    elif is_dir and poses:
        _print_import(*import_image_folder(path, out, poses=poses, **frames_args()))
    else:
        _import_tracked_or_bag(ctx, path, out, is_dir, flags, tolerance, name, frames_args)


def _import_tracked_or_bag(
    ctx: typer.Context, path: str, out: str, is_dir: bool, flags: dict[str, Any],
    tolerance: float, name: str | None, frames_args: Callable[[], dict],
) -> None:  # fmt: skip
    """`import` of a ROS 2 bag folder or a points file; the options that apply to camera
    frames only are refused for tracked points (named, not ignored)."""
    from rodctl.recordings.importer import import_points

    given = _given_on_command_line(ctx)
    t = _bag_topics(flags)
    if is_dir:
        if not t["image_topic"]:
            frames = tuple(n for n, where in _ONLY_FOR.items() if where == _FRAMES)
            _refuse_options(given, path, "a bag of tracked points", frames)
        _import_bag_folder(path, out, t, tolerance, name, frames_args)
        return
    _refuse_options(given, path, "a file of tracked points", tuple(_ONLY_FOR))
    typer.echo(str(import_points(path, out, name)))


@app.command("export")
@user_errors
def export_run(
    path: Annotated[str, typer.Argument(help="A run directory or its run.mcap.")],
    ros2: Annotated[str, typer.Option("--ros2", help="The ROS 2 bag folder to write (new).")],
    storage: Annotated[
        str, typer.Option("--storage", help="Bag storage: mcap or sqlite3.")
    ] = "mcap",
    recover: RecoverOpt = False,
) -> None:
    """Write a run as a ROS 2 bag (Image, CameraInfo, PoseStamped, MarkerArray; CDR), no
    ROS 2 install needed (docs/recordings.md). Prints the messages per topic and the bag last."""
    from rodctl.recordings.ros2 import export_ros2

    with sigterm_as_interrupt():  # SIGTERM too removes the unfinished bag
        counts = export_ros2(path, ros2, storage, recover=recover)
    for topic, n in counts.items():
        typer.echo(f"{topic}: {n} messages", err=True)
    typer.echo(ros2)


def main() -> None:
    """Console-script entry point. Click's own usage errors (an unknown option, a missing
    argument, a value of the wrong type) are one `error:` line naming what is wrong, then the
    usage line, exit 2, as rodctl's own bad-input errors are (not Typer's boxed panel); a
    Ctrl-C that no command's own handler takes says so, exit 1 (an interrupted run's code)."""
    import signal

    signal.signal(signal.SIGINT, signal.default_int_handler)  # after `_entry.quiet_start`
    try:
        code = app(prog_name="rodctl", standalone_mode=False)
    except typer.TyperException as exc:  # typer's click's usage errors derive from it
        if type(exc).__name__ != "NoArgsIsHelpError":  # `rodctl` alone: typer printed help
            _usage_error(exc)
        code = exc.exit_code
    except typer.Abort:
        typer.echo("error: aborted", err=True)
        code = 1
    if code == 130:  # Typer's answer to a KeyboardInterrupt no command handled
        typer.echo("error: interrupted by SIGINT", err=True)
        code = 1  # one rule for every command: interrupted is exit 1 (RunFailed's code)
    sys.exit(code if isinstance(code, int) else 0)


def _usage_error(exc: Any) -> None:
    """A click usage error as rodctl words its errors: `error: …`, then the usage line."""
    typer.echo(f"error: {exc.format_message()}", err=True)
    ctx = getattr(exc, "ctx", None)
    if ctx is not None:
        typer.echo(ctx.get_usage(), err=True)
        typer.echo(f"Try '{ctx.command_path} --help' for help.", err=True)


if __name__ == "__main__":  # pragma: no cover
    main()
