"""report.html and statistics.json of a plain compare: paired statistics against the reference,
a verdict per method, markdown rendered by a real parser, every figure shown in a real browser."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
import urllib.request

import numpy as np
import pytest

from rodctl import report
from rodctl.statistics import PairedDifference, paired_difference

CHROMIUM = "/usr/bin/chromium"


@pytest.mark.slow
def test_a_plain_compare_writes_statistics_and_a_report(compare_smoke_run):
    folder = compare_smoke_run
    stats = json.loads((folder / "statistics.json").read_text(encoding="utf-8"))
    methods = json.loads((folder / "results.json").read_text(encoding="utf-8"))["config"]
    others = [m for m in methods["methods"] if m != "paper-bezier"]  # the first is the reference
    assert list(stats) == others
    for m in others:
        d = stats[m]["steps_to_converge"]
        assert d["n"] == 2 and d["ci_low"] <= d["mean"] <= d["ci_high"]
        assert stats[m]["success"] == [0, 2, 0]  # every method converged on both targets
    summary = (folder / "summary.md").read_text(encoding="utf-8")
    assert "Paired against **paper-bezier**" in summary
    # One verdict per method; two targets are too few for a signed-rank test.
    verdicts = [
        line for line in summary.splitlines() if line.startswith("- ") and "steps [" in line
    ]
    assert len(verdicts) == len(others)
    assert all("not significant" in v and "too few to test" in v for v in verdicts)
    page = (folder / "report.html").read_text(encoding="utf-8")
    assert "<em>paired</em>" in page and "*paired*" not in page  # a real markdown parser
    assert "<table" in page and "| method |" not in page
    # Figures in reading order, each linking to its file, captions naming the target drawn.
    order = re.findall(r'<a href="figures/([a-z0-9_]+\.png)"', page)
    assert order == [name for name, _ in report.FIGURES]
    captions = re.findall(r"<figcaption>(.*?)</figcaption>", page)
    target = json.loads((folder / "results.json").read_text())["figure_target"]
    assert all(f"target {target} (difficulty" in c for c in captions[1:]), captions
    assert not re.search(r"""(src|href)=["']https?://""", page)  # opens with no network


def test_a_verdict_says_what_the_statistics_say():
    rng = np.random.default_rng(0)
    ref = list(rng.uniform(20, 30, 30))
    faster = paired_difference([r - 3.0 + rng.normal(0, 0.5) for r in ref], ref)
    line = report.verdict("ma2022", "paper", faster)
    assert line.startswith("ma2022 \u22122.9 steps [") and "significant (p = " in line
    assert "not significant" not in line and "30 paired targets" in line
    same = paired_difference([r + rng.normal(0, 0.5) for r in ref], ref)
    assert "not significant (p = " in report.verdict("ma2022", "paper", same)
    none = PairedDifference(0, None, None, None, None, 0, 0, 0)
    assert "no target" in report.verdict("ma2022", "paper", none)
    # No episode converged: the metric is absent, the verdict says there is nothing to compare.
    [line] = [x for x in report.verdict_lines("paper", {"ma2022": {}}) if x.startswith("- ")]
    assert "no target" in line


def test_markdown_is_rendered_and_raw_html_escaped():
    out = report.render_markdown("a *b* **c** `d`\n\n| x | y |\n|---|---|\n| 1 | <i>2</i> |\n")
    assert "<em>b</em>" in out and "<strong>c</strong>" in out and "<code>d</code>" in out
    assert "<td>1</td>" in out and "&lt;i&gt;2&lt;/i&gt;" in out


def _chromium_or_skip() -> str:
    if os.path.exists(CHROMIUM):
        return CHROMIUM
    if os.environ.get("CI") == "true":  # .ci/run installs it: missing there is a failure
        pytest.fail(f"{CHROMIUM} is missing under CI (.ci/run should have installed it)")
    pytest.skip(f"{CHROMIUM} not installed (apt-get install chromium)")


def _until(what: str, fn, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while True:
        value = fn()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.05)


@pytest.mark.slow
def test_report_renders_in_headless_chromium_with_every_figure_visible(compare_smoke_run, tmp_path):
    from websockets.sync.client import connect

    browser = _chromium_or_skip()
    url = (compare_smoke_run / "report.html").resolve().as_uri()
    profile = tmp_path / "profile"
    flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--no-first-run",
        f"--user-data-dir={profile}",
        "--remote-debugging-port=0",  # Chromium picks one and writes it to DevToolsActivePort
        "--window-size=1400,1000",
    ]
    with (tmp_path / "chromium.log").open("wb") as log:
        proc = subprocess.Popen([browser, *flags, url], stdout=log, stderr=log)
    try:
        port_file = profile / "DevToolsActivePort"
        port = _until(
            "Chromium's DevTools port",
            lambda: port_file.is_file() and port_file.read_text().split(),
        )[0]

        def page_ws():
            with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
                pages = [t for t in json.load(r) if t.get("type") == "page"]
            return pages and pages[0]["webSocketDebuggerUrl"]

        with connect(_until("the page", page_ws), max_size=None, open_timeout=30) as ws:
            ids = iter(range(1, 1000))

            def evaluate(expression: str):
                i = next(ids)
                params = {"expression": expression, "awaitPromise": True, "returnByValue": True}
                ws.send(json.dumps({"id": i, "method": "Runtime.evaluate", "params": params}))
                while True:
                    msg = json.loads(ws.recv(timeout=60))
                    if msg.get("id") == i:
                        return msg.get("result", {}).get("result", {}).get("value")

            state = "document.readyState === 'complete' && location.href"
            _until("the report to load", lambda: evaluate(state) == url)
            images = evaluate(
                "Promise.all([...document.images].map(i => i.decode().catch(() => null)))"
                ".then(() => [...document.images].map(i => ({alt: i.alt, "
                "w: i.naturalWidth, shown: i.getBoundingClientRect().width})))"
            )
            text = evaluate("document.body.innerText")
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        shutil.rmtree(profile, ignore_errors=True)
    assert len(images) == len(report.FIGURES), images
    for img in images:
        assert img["w"] > 0 and img["shown"] > 0, img
    assert "not significant" in text and "*paired*" not in text
