"""SIGINT and SIGTERM at every start-up phase (imports, model load, first map) and in every lifecycle state
(active under traffic, unconfigured, inactive, deactivated, cleaned up), each once: the node exits 0, without a
traceback, every time (``hjrno bench signals`` runs 32 and more)."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("rclpy")

pytestmark = pytest.mark.real_time  # runs a node over DDS in real time (test/conftest.py)


def test_every_signal_at_every_moment_exits_cleanly(tmp_path):
    from hjrno_ros.tools import signal_bench

    moments = len(signal_bench.MOMENTS) * len(signal_bench.SIGNALS)
    assert signal_bench.run(tmp_path, signals=moments, progress=lambda line: None) == 0
    trials = json.loads((tmp_path / "signals.json").read_text())["trials"]
    assert len(trials) == moments and {(t["moment"], t["signal"]) for t in trials} == {
        (m, s.name) for m in signal_bench.MOMENTS for s in signal_bench.SIGNALS}
    assert all(t["reached"] and t["exit"] == 0 and not t["traceback"] for t in trials), trials
    assert "| active | SIGTERM | 1 | 1 | 1 | 0 |" in (tmp_path / "signals.md").read_text()
