"""The recorder's bookkeeping on its own: board time, micros()/seq wraps, drops, resets, clock rate.

No thread, no port: each case is a list of (t_us, seq) built from the protocol's rules with a known answer.
"""

import numpy as np
import pytest

from kfkit.capture.protocol import MICROS_MODULO, SEQ_MODULO
from kfkit.capture.timeline import CaptureStats, Timeline


def feed(timeline, samples):
    return [timeline.place(t_us, seq) for t_us, seq in samples]


def test_first_sample_is_time_zero_and_time_follows_the_board_clock():
    tl = Timeline(100.0)
    t = feed(tl, [(5_000_123 + 10_000 * k, 7 + k) for k in range(5)])
    assert t == [0.0, 0.01, 0.02, 0.03, 0.04]
    assert tl.placed == 5 and tl.elapsed == 0.04
    assert (tl.stats.dropped, tl.stats.resets, tl.stats.malformed) == (0, 0, 0)


def test_micros_and_seq_wrap_keep_time_continuous_and_count_nothing():
    start_us, start_seq = MICROS_MODULO - 25_000, SEQ_MODULO - 2
    samples = [((start_us + 10_000 * k) % MICROS_MODULO, (start_seq + k) % SEQ_MODULO) for k in range(6)]
    assert samples[3][0] < samples[2][0] and samples[2][1] == 0  # both counters wrapped inside the run
    tl = Timeline(100.0)
    assert feed(tl, samples) == pytest.approx(np.arange(6) * 0.01, abs=1e-12)
    assert (tl.stats.dropped, tl.stats.resets) == (0, 0)


def test_a_seq_gap_counts_the_missing_samples_where_the_first_was_due():
    kept = [k for k in range(10) if k not in (4, 5, 6)]
    tl = Timeline(100.0)
    t = feed(tl, [(10_000 * k, k) for k in kept])
    assert t == pytest.approx([0.01 * k for k in kept], abs=1e-12)
    # 3 missing before the 5th sample placed (index 4), the first of them due at 0.04 s
    assert tl.stats.dropped == 3 and tl.stats.drops == [(4, 0.04, 3)]


def test_time_going_backwards_is_a_reset_and_time_goes_on_one_nominal_period_later():
    tl = Timeline(50.0)
    t = feed(tl, [(1_000_000, 100), (1_020_000, 101), (3_000, 0), (23_000, 1)])
    assert t == pytest.approx([0.0, 0.02, 0.04, 0.06], abs=1e-12)
    assert tl.stats.resets == 1 and tl.stats.reset_positions == [2]
    assert tl.stats.dropped == 0  # a reset is no gap


def test_a_repeated_header_then_seq_zero_is_a_reset_even_when_the_clock_steps_forwards():
    # after 35.8 min (2^31 µs) a restarted board's micros() looks like a step forward: only the header says so
    tl = Timeline(100.0)
    feed(tl, [(0, 500), (10_000, 501)])
    tl.header_again()
    assert tl.place(20_000 + 4_000_000, 0) == pytest.approx(0.02)
    assert tl.stats.resets == 1 and tl.stats.dropped == 0


def test_a_repeated_header_answering_h_is_no_reset_and_is_forgotten_after_one_sample():
    tl = Timeline(100.0)
    feed(tl, [(0, 0), (10_000, 1)])
    tl.header_again()  # the answer to 'h': the count goes on
    assert tl.place(20_000, 2) == pytest.approx(0.02)
    assert tl.stats.resets == 0
    tl.header_again()
    tl.place(30_000, 3)
    assert tl.place(40_000 + 2**20, 0) is not None and tl.stats.resets == 0  # seq back at 0 with no header: a gap
    assert tl.stats.dropped == SEQ_MODULO - 4


def test_the_same_instant_twice_is_malformed_and_not_placed():
    tl = Timeline(100.0)
    assert feed(tl, [(0, 0), (10_000, 1), (10_000, 2), (20_000, 2)]) == [0.0, 0.01, None, 0.02]
    assert tl.stats.malformed == 1 and tl.placed == 3 and tl.stats.dropped == 0


def test_a_sample_at_the_end_is_not_placed_and_ends_the_capture():
    tl = Timeline(100.0, seconds=0.05)
    t = feed(tl, [(10_000 * k, k) for k in range(8)])
    assert t[:5] == pytest.approx([0.0, 0.01, 0.02, 0.03, 0.04]) and t[5:] == [None] * 3
    assert tl.reached and tl.placed == 5 and tl.elapsed == pytest.approx(0.04)


def test_clock_rate_counts_gap_periods_and_leaves_resets_out():
    period_us = 9_615  # a 104 Hz board whose crystal gives 1e6 / 9615 = 104.0042 Hz
    samples = [(period_us * k, k) for k in range(200) if k not in (50, 51)]  # a gap of 2 spans 3 periods
    samples += [(7_000 + period_us * k, k) for k in range(100)]  # a reset: its jump is no period
    tl = Timeline(104.0)
    assert np.isnan(tl.clock_rate_hz())
    feed(tl, samples)
    assert tl.stats.resets == 1 and tl.stats.dropped == 2
    assert tl.clock_rate_hz() == float(f"{1e6 / period_us:.6g}")


def test_summary_rate_interval_and_jitter_against_numpy():
    rng = np.random.default_rng(3)
    dt_us = 10_000 + rng.integers(-40, 41, size=300)
    t_us = np.concatenate([[0], np.cumsum(dt_us)])
    seq = np.arange(len(t_us))
    keep = np.ones(len(t_us), bool)
    keep[100] = False  # one dropped sample: the interval across it is left out of the mean and jitter
    stats = CaptureStats()
    tl = Timeline(100.0, stats=stats)
    feed(tl, zip(t_us[keep].tolist(), seq[keep].tolist()))
    tl.summarise()
    gaps_out = np.diff(t_us)[[k for k in range(len(dt_us)) if k not in (99, 100)]]
    assert stats.dt_mean_us == pytest.approx(gaps_out.mean(), rel=1e-12)
    assert stats.jitter_us == pytest.approx(gaps_out.std(), rel=1e-9)
    assert stats.rate_hz == pytest.approx((keep.sum() - 1) / (t_us[-1] * 1e-6), rel=1e-9)
    due = (t_us[99] + (t_us[101] - t_us[99]) / 2) * 1e-6  # one interval of two after the sample before the gap
    assert stats.drops == [(100, pytest.approx(due, abs=1e-6), 1)]


def test_summary_of_fewer_than_two_samples_leaves_the_rates_unknown():
    stats = CaptureStats()
    tl = Timeline(100.0, stats=stats)
    tl.place(123, 9)
    tl.summarise()
    assert np.isnan(stats.rate_hz) and np.isnan(stats.dt_mean_us) and np.isnan(stats.jitter_us)


def test_the_recorder_takes_any_board_object_that_describes_itself(tmp_path):
    """Not only a VirtualBoard: whatever serves a port and says what it is (description, source, phases)."""
    from kfkit.capture import Recorder, VirtualBoard

    class Rig:  # a board object of someone else's: it serves a virtual board's pty under its own name
        source, phases = "capture (test rig)", [{"label": "warm-up", "start": 0.0, "end": 0.1}]

        def __init__(self):
            self.inner, self.port, self.closed = VirtualBoard(board="mpu6050", realtime=False), None, False

        @property
        def description(self):
            return f"test rig on {self.port}"

        def start(self):
            self.port = self.inner.start().port
            return self

        def close(self):
            self.inner.close()
            self.closed = True

    rig = Rig()
    recorder = Recorder(rig, out=tmp_path / "rig.csv", seconds=0.3)
    rec = recorder.run()
    assert recorder.description == f"test rig on {rig.port}" and rig.closed  # started by the recorder: closed by it
    assert rec.meta["source"] == "capture (test rig)" and rec.meta["phases"] == Rig.phases
    assert len(rec) == 30 and rec.meta["board"] == "mpu6050"
