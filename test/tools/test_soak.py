"""The soak's memory verdict: RSS growth per minute by least squares, after the start-up minute."""

from __future__ import annotations

import pytest

from hjrno_ros.tools.soak_bench import WARMUP_S, rss_slope


def test_rss_slope_is_mb_per_minute_after_the_warmup():
    start_up = [(t, 150.0 + t) for t in range(0, int(WARMUP_S), 10)]  # start-up growth: left out
    steady = [(WARMUP_S + 60.0 * k, 220.0 + 0.25 * k) for k in range(10)]  # 0.25 MB a minute
    assert rss_slope(start_up + steady) == pytest.approx(0.25)
    assert rss_slope(start_up + steady[:2]) is None  # too few samples to say
    flat = [(WARMUP_S + 10.0 * k, 223.4) for k in range(30)]
    assert rss_slope(flat) == pytest.approx(0.0, abs=1e-9)
