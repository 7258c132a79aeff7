"""Keyframes at 0.5 s form five-image windows sharing two images; the bounded queue drops the oldest."""
from __future__ import annotations

import numpy as np

from runtime.events import Frame
from runtime.mapping.config import MappingConfig
from runtime.mapping.windows import MappingWindow, WindowBuilder, WindowQueue


def _frames(seconds: float, rate: float = 20.0):
    n = int(seconds * rate)
    img = np.zeros((4, 4), np.uint8)
    return [Frame(int(round(k * 1e9 / rate)), img) for k in range(n)]


def test_windows_of_five_keyframes_share_two_images():
    wb = WindowBuilder(MappingConfig())
    windows = [w for f in _frames(6.0) if (w := wb.add(f, np.eye(4))) is not None]
    assert wb.keyframes == 12                        # every 0.5 s over 6 s at 20 Hz
    kf_t = [int(k * 0.5e9) for k in range(12)]
    assert [list(w.t_ns) for w in windows] == [kf_t[0:5], kf_t[3:8], kf_t[6:11]]
    for a, b in zip(windows, windows[1:], strict=False):
        assert len(set(a.t_ns) & set(b.t_ns)) == 2


def test_a_new_segment_starts_a_new_window():
    wb = WindowBuilder(MappingConfig())
    frames = _frames(4.0)
    out = [wb.add(f, np.eye(4), segment=0 if f.t_ns < 1.6e9 else 1) for f in frames]
    windows = [w for w in out if w is not None]
    assert all(w.segment == 1 for w in windows)      # the 4 keyframes of segment 0 never formed one
    assert windows[0].t_ns[0] >= 1.6e9


def test_queue_drops_the_oldest_pending_window_and_counts_it():
    q = WindowQueue(2)
    ws = [MappingWindow(k, [], np.zeros((0, 4, 4)), 0) for k in range(4)]
    assert q.put(ws[0]) is None and q.put(ws[1]) is None
    assert q.put(ws[2]).window_id == 0
    assert q.put(ws[3]).window_id == 1
    assert q.dropped == [0, 1]
    assert [q.pop().window_id, q.pop().window_id] == [2, 3] and q.pop() is None
