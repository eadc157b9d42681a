"""The `rodctl` command line. Each command is a thin function: load the config, call in.

Bad input (a missing file, invalid YAML, an unknown key, a value out of range, a malformed `--set`)
raises `UserError`; `user_errors` turns it into one short message on stderr and exit code 2.
"""

from __future__ import annotations

import functools
import json
import sys
from collections.abc import Callable
from typing import Annotated, Any, TypeVar

import typer

from rodctl.config import ExperimentConfig, dump_config, load_config
from rodctl.errors import UserError

F = TypeVar("F", bound=Callable[..., Any])

app = typer.Typer(
    name="rodctl",
    help="Experiment runner for vision-based shape servoing of elastic rods.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)
config_app = typer.Typer(
    help="Inspect configs: print a resolved config or the JSON schema.",
    no_args_is_help=True,
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
    """Print a `UserError` as one message on stderr and exit 2 instead of a traceback."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except UserError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


@config_app.command("show")
@user_errors
def config_show(config: ConfigArg, set_: SetOpt = None) -> None:
    """Print the resolved config (YAML, every default filled in) after --set overrides."""
    cfg = load_config(config, set_ or [])
    typer.echo(dump_config(cfg), nl=False)


@config_app.command("schema")
def config_schema() -> None:
    """Print the JSON schema of the experiment config."""
    typer.echo(json.dumps(ExperimentConfig.model_json_schema(), indent=2))


OutOpt = Annotated[
    str, typer.Option("--out", help="Parent folder of the run directory.", show_default=True)
]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or table.")]


@app.command()
@user_errors
def simulate(
    config: ConfigArg,
    set_: SetOpt = None,
    out: OutOpt = "runs",
    quiet: QuietOpt = False,
) -> None:
    """Run one shape-servoing experiment; print the run directory as the last line.

    Exit code 0 when the run completed (converged or not: see summary.json), 1 when it
    failed (diverged, lost the rod, crashed) or was interrupted, 2 on bad input.
    """
    from rodctl.display import print_summary, step_progress
    from rodctl.simulate import simulate as run_simulation

    cfg = load_config(config, set_ or [])
    with step_progress(cfg.run.max_steps, enabled=not quiet) as on_step:
        result = run_simulation(cfg, out, argv=sys.argv, on_step=on_step)
    if not quiet:
        print_summary(result.summary)
    if result.error:
        typer.echo(f"error: {result.error}", err=True)
    typer.echo(str(result.run.path))
    raise typer.Exit(code=result.exit_code)


def main() -> None:
    """Console-script entry point."""
    app(prog_name="rodctl")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
