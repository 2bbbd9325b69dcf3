"""Per-pulse random streams: numba and Python agree, seeds are stable and distinct."""

from __future__ import annotations

import numpy as np

from fwcore.rng import SplitMix64, next_u64, pulse_seed


def test_numba_and_python_random_streams_agree():
    state = np.array([12345], dtype=np.uint64)
    ref = SplitMix64(12345)
    assert [int(next_u64(state)) for _ in range(5)] == [ref.next_u64() for _ in range(5)]


def test_pulse_seed_is_stable_and_distinct():
    assert pulse_seed(0, 92) == pulse_seed(0, 92)
    assert len({pulse_seed(0, o) for o in range(1000)}) == 1000
    assert pulse_seed(1, 92) != pulse_seed(0, 92) and pulse_seed(0, 92, 1) != pulse_seed(0, 92)
