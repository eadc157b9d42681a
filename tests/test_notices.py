"""A notice (a checkpoint used on another set-up) is said once per run, not once per worker."""

from __future__ import annotations

import subprocess
import sys

from rodctl import notices


def test_a_notice_is_said_once_per_run_across_worker_processes(monkeypatch, capfd):
    # setenv first, so that the teardown removes what share_with_workers sets (a delenv of an
    # unset variable records nothing to undo, and the folder would leak into later tests)
    monkeypatch.setenv(notices.ENV, "")
    monkeypatch.delenv(notices.ENV)
    monkeypatch.setattr(notices, "_SAID", set())
    notices.say_once("transfer A", "said by the command")
    notices.say_once("transfer A", "said by the command")  # once in a process, as before
    notices.share_with_workers()  # what the local executor does before it spawns its workers
    # rodctl as a bare package (its `__init__` imports gymnasium: seconds on a loaded machine)
    code = (
        "import sys, types\n"
        f"package = types.ModuleType('rodctl'); package.__path__ = [{notices.__file__[:-11]!r}]\n"
        "sys.modules['rodctl'] = package\n"
        "from rodctl.notices import say_once\n"
        "say_once('transfer A', 'said again by a worker')\n"
        "say_once('transfer B', 'first said by a worker')\n"
    )
    for _ in range(2):  # two workers, each validating the same configs
        subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    notices.say_once("transfer B", "said again by the command")
    err = capfd.readouterr().err
    assert err.count("said by the command") == 1
    assert "said again" not in err
    assert err.count("first said by a worker") == 1
