"""`rodctl.signals`: the one helper every stop policy swaps SIGINT / SIGTERM handlers with."""

from __future__ import annotations

import os
import signal
import threading

from rodctl import signals


def test_a_handler_is_set_for_the_block_and_the_previous_one_put_back():
    seen: list[str] = []
    before = signal.getsignal(signal.SIGTERM)
    with signals.handled(lambda signum, _f: seen.append(signals.name(signum))) as previous:
        assert set(previous) == {signal.SIGINT, signal.SIGTERM}
        os.kill(os.getpid(), signal.SIGTERM)  # delivered to the main thread before kill returns
    assert seen == ["SIGTERM"]
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_ignored_signal_stays_ignored_unless_asked():
    old = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        with signals.handled(lambda *_: None) as previous:
            assert signal.SIGTERM not in previous
            assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
        with signals.handled(lambda *_: None, over_ignored=True) as previous:
            assert previous[signal.SIGTERM] is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGTERM, old)


def test_outside_the_main_thread_nothing_is_touched():
    before = signal.getsignal(signal.SIGINT)
    got: list[dict] = []

    def worker() -> None:
        with signals.handled(lambda *_: None) as previous:
            got.append(previous)
            got.append({"now": signal.getsignal(signal.SIGINT)})

    t = threading.Thread(target=worker)
    t.start()
    t.join(timeout=60)
    assert got == [{}, {"now": before}]
