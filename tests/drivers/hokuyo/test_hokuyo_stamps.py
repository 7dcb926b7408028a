"""Device clock: 24-bit unwrap with the half-range rule, TM offset, drift from stream stamps."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.hokuyo.stamps import ClockSample, DeviceClock, TimestampUnwrapper

M = 1 << 24


def test_unwrap_across_the_wrap() -> None:
    unwrapper = TimestampUnwrapper()
    raw = [M - 50, M - 25, 0, 25, 50]
    assert [unwrapper.unwrap(r) for r in raw] == [M - 50, M - 25, M, M + 25, M + 50]


def test_small_backward_step_is_not_a_wrap() -> None:
    unwrapper = TimestampUnwrapper()
    assert [unwrapper.unwrap(r) for r in (1000, 990, 1010)] == [1000, 990, 1010]


def test_late_stamp_from_before_the_wrap() -> None:
    unwrapper = TimestampUnwrapper()
    assert [unwrapper.unwrap(r) for r in (M - 10, 5, M - 3, 30)] == [M - 10, M + 5, M - 3, M + 30]


def test_reset_forgets_history() -> None:
    unwrapper = TimestampUnwrapper()
    unwrapper.unwrap(M - 10)
    unwrapper.unwrap(5)
    unwrapper.reset()
    assert unwrapper.unwrap(7) == 7


@given(start=st.integers(0, 10 * M), steps=st.lists(st.integers(0, M // 2 - 1), max_size=60))
def test_unwrap_recovers_any_sequence_with_steps_below_half_range(start: int, steps: list[int]) -> None:
    truth = start + np.cumsum([0, *steps])
    unwrapper = TimestampUnwrapper()
    unwrapped = [unwrapper.unwrap(int(t) % M) for t in truth]
    base = start - start % M
    assert unwrapped == [int(t) - base for t in truth]


def test_tm_anchor_uses_the_shortest_round_trip() -> None:
    clock = DeviceClock()
    samples = [
        ClockSample(100.000, 100.010, 5000),  # slow exchange, midpoint off by 4 ms
        ClockSample(100.020, 100.0202, 5021),  # fast one: device 5.021 s at host 100.0201
    ]
    estimate = clock.synchronise(samples)
    assert estimate.source == "tm"
    assert estimate.round_trip_s == pytest.approx(0.0002)
    assert clock.to_host_s(5021) == pytest.approx(100.0201)
    assert clock.to_host_s(6021) == pytest.approx(101.0201)


def simulate_stream(clock: DeviceClock, drift: float, offset_s: float, seconds: float, seed: int = 1):
    rng = np.random.default_rng(seed)
    for k in range(int(seconds / 0.025)):
        device_ms = 1_000_000 + 25 * k
        true_host = offset_s + device_ms / 1000.0 * (1 + drift)
        delay = 0.020 + rng.exponential(0.003)  # scan transmission + scheduling jitter
        clock.observe(device_ms, true_host + delay)
    return 1_000_000 + 25 * (int(seconds / 0.025) - 1)


def test_drift_is_estimated_from_the_stream_envelope() -> None:
    clock = DeviceClock(stream_delay_s=0.020)
    last_ms = simulate_stream(clock, drift=80e-6, offset_s=5000.0, seconds=60)
    estimate = clock.estimate()
    assert estimate.source == "stream"
    assert estimate.drift == pytest.approx(80e-6, abs=10e-6)
    true_host = 5000.0 + last_ms / 1000.0 * (1 + 80e-6)
    assert clock.to_host_s(last_ms) == pytest.approx(true_host, abs=0.002)


def test_tm_anchor_keeps_its_offset_and_takes_the_stream_drift() -> None:
    clock = DeviceClock()
    clock.synchronise([ClockSample(6000.0, 6000.0004, 1_000_000)])
    simulate_stream(clock, drift=-50e-6, offset_s=5000.0, seconds=30)
    estimate = clock.estimate()
    assert estimate.source == "tm"
    assert estimate.offset_s == pytest.approx(5000.0002)
    assert estimate.drift == pytest.approx(-50e-6, abs=15e-6)


def test_device_time_going_backwards_clears_the_history() -> None:
    clock = DeviceClock(stream_delay_s=0.0)
    simulate_stream(clock, drift=0.0, offset_s=10.0, seconds=10)
    clock.observe(1000, 7.0)  # counter restarted (RS): host = 6 + 1 s
    assert clock.estimate().offset_s == pytest.approx(6.0)
