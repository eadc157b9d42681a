"""The first thing the `rodctl` command does: when its command line says `simulate`, fork the run's
helper processes (the figure and Rerun processes, `rodctl.helper_process`) before anything else
is imported.

Why (issue #24): the helpers' own imports (matplotlib ~0.5 s of CPU, rerun ~0.5 s) are the
longest part of `rodctl simulate`; started only after the command's imports (typer, the pydantic
config models, gymnasium, cv2: ~0.4 s) and its config, they were still importing when the episode
ended. Forked here they begin at once and get the interpreter and numpy with the fork; the config
(and the run) is handed to them later, by the sinks that take them (`Helpers.start`).

What is peeked at, cheaply (no config model, no YAML parser: a hostile file must meet the
loader's guards first): whether this process is the `rodctl` command (the console script, or
`python -m rodctl`), whether its command is `simulate` (not its --help), and whether the config
file's `logging:` block or a `--set logging.figures=…` / `logging.rerun=…` switches a helper's
job off. A wrong guess costs time only: a helper the config does not need is stopped when the
config is loaded (`helper_process.stop_early`), one not forked here is started then, as before.
Only on Linux (elsewhere fork is unsafe or absent, and the helpers are spawned as before).
"""

from __future__ import annotations

import os
import re
import sys

#: The helpers of a `simulate` run: (config key under `logging`, module, name in messages). The
#: figure process first: it has the longer way to go.
JOBS = (
    ("figures", "rodctl.figure_worker", "figure process"),
    ("rerun", "rodctl.logs.rerun_process", "Rerun process"),
)

#: `simulate`'s options that take a value (the value is not the config file).
_VALUED = ("-o", "--out", "--set", "--live-port", "--live-rerun")
#: YAML 1.1's words for false and true (what the config loader reads).
_FALSE = {"false", "False", "FALSE", "no", "No", "NO", "off", "Off", "OFF"}
_TRUE = {"true", "True", "TRUE", "yes", "Yes", "YES", "on", "On", "ON"}
_KEY = re.compile(r"^\s+(figures|rerun)\s*:\s*([A-Za-z]+)\s*(#.*)?$")


def command_args() -> list[str] | None:
    """The arguments of this process if it is the `rodctl` command, else None (a library use,
    a test process)."""
    argv = sys.argv
    if not argv:
        return None
    if argv[0] == "-m":  # `python -m rodctl`, while the package is found and imported
        orig = list(getattr(sys, "orig_argv", ()))
        at = orig.index("-m") if "-m" in orig else -1
        return argv[1:] if at >= 0 and orig[at + 1 : at + 2] == ["rodctl"] else None
    return argv[1:] if os.path.basename(argv[0]) == "rodctl" else None


def wanted(args: list[str]) -> list[tuple[str, str]]:
    """(module, name) of the helpers a `simulate` command line `args` (after `simulate`) will
    likely need, from the config file's `logging:` block and the `--set`s (module docstring)."""
    config, sets, rest = None, [], iter(args)
    for arg in rest:
        if arg == "--set":
            sets.append(next(rest, ""))
        elif arg.startswith("--set="):
            sets.append(arg[len("--set=") :])
        elif arg in _VALUED:
            next(rest, None)
        elif not arg.startswith("-") and config is None:
            config = arg
    on = {key: True for key, _, _ in JOBS}
    on.update(_logging_block(config))
    for item in sets:
        key, _, value = item.partition("=")
        name = key.strip().removeprefix("logging.")
        if key.strip().startswith("logging.") and name in on and value.strip() in _FALSE | _TRUE:
            on[name] = value.strip() in _TRUE
    return [(module, name) for key, module, name in JOBS if on[key]]


def _logging_block(config: str | None) -> dict[str, bool]:
    """What the config file's block-style `logging:` mapping sets `figures` and `rerun` to
    (nothing known: {})."""
    found: dict[str, bool] = {}
    if not config or not os.path.isfile(config):  # a FIFO would block here: the loader refuses it
        return found
    try:
        with open(config, encoding="utf-8", errors="replace") as f:
            text = f.read(1 << 18)
    except (OSError, ValueError):
        return found
    inside = False
    for line in text.splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if not line[0].isspace():
            inside = line.split("#")[0].strip() == "logging:"
        elif inside and (m := _KEY.match(line)) and m.group(2) in _FALSE | _TRUE:
            found[m.group(1)] = m.group(2) in _TRUE
    return found


def quiet_start() -> None:
    """For the `rodctl` command only: a Ctrl-C while rodctl is still being imported (the first
    ~0.2 s: the helpers' fork, gymnasium) ends it with one line and exit 1 instead of an
    import traceback. `rodctl.cli.main` puts Python's own handler back once the import is done;
    a library use (a notebook) keeps Python's handler throughout."""
    if command_args() is None:
        return
    import signal  # noqa: PLC0415

    def starting(signum: int, frame: object) -> None:
        sys.stderr.write("error: interrupted by SIGINT while rodctl was starting\n")
        raise SystemExit(1)

    signal.signal(signal.SIGINT, starting)


def start_helpers() -> None:
    """Fork the helpers a `rodctl simulate` command line needs (module docstring); nothing for
    any other process or command."""
    args = command_args()
    if not args or not sys.platform.startswith("linux") or "--help" in args:
        return
    words = [a for a in args if not a.startswith("-")]
    if not words or words[0] != "simulate":
        return
    jobs = wanted(args[args.index("simulate") + 1 :])
    if not jobs:
        return
    import importlib  # noqa: PLC0415

    import numpy  # noqa: F401, PLC0415 - the helpers get it with the fork (helper_process)
    import yaml  # noqa: F401, PLC0415 - and what both sides import anyway: the config's YAML,

    for _, module, _ in JOBS:  # the jobs' modules (records, codec: no thread started)
        importlib.import_module(module)
    from rodctl import helper_process  # noqa: PLC0415

    helper_process.start_early(jobs)
