"""The output sinks a run writes to, registered like stages (`rodctl.registry.SINKS`).

A sink type is a config model derived from `SinkConfig` (a `type` literal and its own options)
and a factory `factory(cfg, ctx: SinkContext) -> Sink` (`rodctl.logs.base.Sink`: `open`,
`write`, `close`). A run writes to the built-in sinks its logging booleans switch on
(`logging.mcap`: run.mcap, `logging.rerun`: run.rrd, `logging.figures`: figures/*.png) and to
every entry of `logging.sinks`, each chosen by its `type`, so a plug-in adds one (a CSV table, a
ROS 2 bag) without editing rodctl::

    class CsvSinkConfig(SinkConfig):
        # (a docstring: what the sink writes, and where)
        type: Literal["csv"] = "csv"
        name: str = Field("steps.csv", description="File name inside the run directory.")

    @SINKS.register(CsvSinkConfig)
    def _build(cfg: CsvSinkConfig, ctx: SinkContext) -> Sink:
        return CsvSink(ctx.run_dir / cfg.name)

The factories here import their writers when called (rerun, mcap and the figure process are
imported only by a run that writes them), so registering them costs nothing at start-up.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Literal

from pydantic import Field

from rodctl.config.base import StrictModel
from rodctl.config.logging import LoggingConfig
from rodctl.registry import SINKS

if TYPE_CHECKING:
    from rodctl.logs.base import Sink

__all__ = [
    "FiguresSinkConfig",
    "LiveSinkConfig",
    "McapSinkConfig",
    "RerunSinkConfig",
    "SinkConfig",
    "SinkContext",
    "make_sink",
    "selected_sinks",
    "start_helpers",
]


@dataclass(frozen=True)
class SinkContext:
    """What a sink factory may need besides its own config.

    Attributes:
        run_dir: the run directory the sink writes into (None for a sink that writes no file,
            e.g. the figure process, which is started before the run directory exists).
        logging: the run's logging config (frame rate, PNG level, flush interval).
        experiment: the whole experiment config, for a sink that records more of it.
        helpers: the `rodctl.helper_process.Helpers` of `rodctl simulate` (`start_helpers`): the
            figures and run.rrd are then written by helper processes; None: in this process
            (the figures still in a helper of their own).
    """

    run_dir: Path | None
    logging: LoggingConfig
    experiment: Any = None
    helpers: Any = None


class SinkConfig(StrictModel):
    """Base of every sink config model."""

    #: The `logging` boolean that selects this built-in sink (None: it is listed in
    #: `logging.sinks`); a sink with a switch is not listed there too.
    switch: ClassVar[str | None] = None


class McapSinkConfig(SinkConfig):
    """run.mcap: the Foxglove-compatible log of every step (the contract topics), its options
    in `logging` (compression, chunk size, flush interval)."""

    type: Literal["mcap"] = "mcap"
    switch: ClassVar[str | None] = "mcap"


class RerunSinkConfig(SinkConfig):
    """run.rrd: the Rerun recording of the run with its blueprint (`logging.flush_every_steps`,
    `logging.image_rate_hz`)."""

    type: Literal["rerun"] = "rerun"
    switch: ClassVar[str | None] = "rerun"


class FiguresSinkConfig(SinkConfig):
    """figures/*.png: the paper's figures, drawn by a helper process started with the run (the
    command waits for them before it returns)."""

    type: Literal["figures"] = "figures"
    switch: ClassVar[str | None] = "figures"


@SINKS.register(McapSinkConfig)
def _mcap(cfg: McapSinkConfig, ctx: SinkContext) -> Sink:
    """`McapSink` writing run_dir/run.mcap."""
    # Lazy, as every writer here (module docstring): registering the sinks, which every command
    # does, must not import mcap, rerun, the figure process or the live server.
    from rodctl.logs.mcap import McapSink  # noqa: PLC0415

    return McapSink(_folder(ctx, "mcap") / "run.mcap", ctx.logging)


@SINKS.register(RerunSinkConfig)
def _rerun(cfg: RerunSinkConfig, ctx: SinkContext) -> Sink:
    """`RerunSink` writing run_dir/run.rrd; with `ctx.helpers`, from a helper process
    (`rodctl.logs.rerun_process`: no rerun in this one)."""
    path = _folder(ctx, "rerun") / "run.rrd"
    if ctx.helpers is not None:
        from rodctl.logs import rerun_process  # noqa: PLC0415 (lazily: `_mcap`)

        helper = ctx.helpers.take(rerun_process.MODULE, rerun_process.NAME)
        return rerun_process.RerunProcessSink(helper, path, ctx.logging)
    from rodctl.logs.rerun import RerunSink  # noqa: PLC0415 (the writer, lazily: `_mcap`)

    return RerunSink(path, ctx.logging)


@SINKS.register(FiguresSinkConfig)
def _figures(cfg: FiguresSinkConfig, ctx: SinkContext) -> Sink:
    """A started `FigureWorker` (it gets the records as a sink; `rodctl.simulate` saves the
    figures it draws and stops it)."""
    from rodctl import figure_worker  # noqa: PLC0415 (lazily: `_mcap`)

    if ctx.helpers is not None:  # started with the command (`start_helpers`)
        return figure_worker.FigureWorker(
            ctx.helpers.take(figure_worker.MODULE, figure_worker.NAME)
        )
    return figure_worker.FigureWorker.start()


def start_helpers(logging: LoggingConfig) -> Any:
    """The helper processes that the built-in sinks of a run with `logging` write through,
    started now so that their imports overlap the command's (`rodctl.helper_process.Helpers`, a
    context manager that stops them; give it to the sinks as `SinkContext.helpers`). The figure
    process first: it has the longer way to go (matplotlib, then drawing after the episode)."""
    from rodctl import figure_worker  # noqa: PLC0415 (lazily: `_mcap`)
    from rodctl.helper_process import Helpers, stop_early  # noqa: PLC0415
    from rodctl.logs import rerun_process  # noqa: PLC0415

    helpers = Helpers()  # it takes those the entry point forked (`rodctl._entry`)
    if logging.figures:
        helpers.start(figure_worker.MODULE, figure_worker.NAME)
    if logging.rerun:
        helpers.start(rerun_process.MODULE, rerun_process.NAME)
    stop_early()  # forked for a job this config switches off
    return helpers


class LiveSinkConfig(SinkConfig):
    """The run streamed to the Foxglove app as it runs (the Foxglove WebSocket protocol on
    loopback; `pip install 'rodctl[live]'`): the messages of run.mcap, step by step. The server
    stops when the run ends. `simulate --live` is this sink with a wait for the viewer."""

    type: Literal["live"] = "live"
    port: int = Field(
        8765, ge=0, le=65535, description="Loopback port (0: any free one; the URL goes to stderr)."
    )
    wait_s: float = Field(
        0.0,
        ge=0.0,
        le=3600.0,
        description="Seconds to wait for a viewer to subscribe before the first step (0: none).",
    )
    grace_s: float = Field(
        0.5, ge=0.0, le=60.0, description="Seconds the last messages get before the server stops."
    )


class _ServedView:
    """A started `LiveView` as a sink that waits for a viewer at `open` (up to `wait_s`) and
    stops its server at `close` (the `LiveView` itself leaves that to its owner)."""

    def __init__(self, view: Any, wait_s: float) -> None:
        self.view, self.wait_s = view, wait_s

    def open(self, header: Any) -> None:
        if self.wait_s > 0:
            self.view.wait_for_client(timeout=self.wait_s)
        self.view.open(header)

    def write(self, record: Any) -> None:
        self.view.write(record)

    def close(self, summary: Any, status: str) -> None:
        try:
            self.view.close(summary, status)
        finally:
            self.view.stop(self.view.grace_s)


@SINKS.register(LiveSinkConfig)
def _live(cfg: LiveSinkConfig, ctx: SinkContext) -> Sink:
    """A started `LiveView` on 127.0.0.1:`port`, stopped when the run closes its sinks."""
    from rodctl.logs.live import LiveView  # noqa: PLC0415 (the server, lazily: `_mcap`)

    arms = ctx.experiment.rod.arms if ctx.experiment is not None else 1
    view = LiveView(ctx.logging, port=cfg.port, grace_s=cfg.grace_s, arms=arms).start()
    print(
        f"live view on {view.url} (Foxglove: Open connection > Foxglove WebSocket)", file=sys.stderr
    )
    return _ServedView(view, cfg.wait_s)


def _folder(ctx: SinkContext, name: str) -> Path:
    if ctx.run_dir is None:
        raise ValueError(f"the {name} sink writes a file: it needs a run directory")
    return Path(ctx.run_dir)


def selected_sinks(logging: LoggingConfig, *, figures: bool = False) -> list[Any]:
    """The config of every sink a run with `logging` writes to, in order: MCAP and Rerun when
    their booleans are on, then `logging.sinks`. `figures`: the figure process too (first),
    when `logging.figures` (`rodctl simulate` starts it before the others)."""
    out: list[Any] = []
    if figures and logging.figures:
        out.append(FiguresSinkConfig())
    if logging.mcap:
        out.append(McapSinkConfig())
    if logging.rerun:
        out.append(RerunSinkConfig())
    return out + list(logging.sinks)


def make_sink(cfg: Any, ctx: SinkContext) -> Sink:
    """The sink `cfg` describes, built by its registered factory."""
    return SINKS.build(cfg, ctx)
