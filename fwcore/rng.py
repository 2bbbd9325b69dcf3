"""A counter-based random stream per waveform, so results never depend on threads.

numba's own np.random state is per thread: with a batch spread over threads the
draws a waveform sees would depend on scheduling. Each waveform instead carries its own
SplitMix64 state, seeded from a stable pulse identity.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT_INLINE

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_INV_2_53 = 1.0 / 9007199254740992.0
_MASK64 = (1 << 64) - 1


@njit(**JIT_INLINE)
def next_u64(state):
    """Advance a one-element uint64 state array; return 64 random bits."""
    state[0] += _GOLDEN
    z = state[0]
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(**JIT_INLINE)
def uniform(state):
    """A float64 uniform in [0, 1)."""
    return np.float64(next_u64(state) >> _S11) * _INV_2_53


@njit(**JIT_INLINE)
def randint(state, n):
    """An integer uniform in [0, n) (modulo bias < n / 2**64)."""
    return np.int64(next_u64(state) % np.uint64(n))


class SplitMix64:
    """The same stream in pure Python, for reference implementations in tests."""

    def __init__(self, seed: int) -> None:
        self.state = seed & _MASK64

    def next_u64(self) -> int:
        self.state = (self.state + 0x9E3779B97F4A7C15) & _MASK64
        z = self.state
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
        return z ^ (z >> 31)

    def uniform(self) -> float:
        return (self.next_u64() >> 11) * _INV_2_53

    def randint(self, n: int) -> int:
        return self.next_u64() % n


def pulse_seeds(seed: int, pulse_id: np.ndarray, segment: np.ndarray | int = 0) -> np.ndarray:
    """64-bit seeds (uint64) from the run seed and each waveform's identity: its pulse id
    (fwcore.io.records.pulse_identity, the same in every encoding of the data) and its
    returning segment within the pulse. No file name enters: a renamed or re-encoded file
    gives the same random streams."""
    pulse_id = np.asarray(pulse_id, dtype=np.int64).astype(np.uint64)
    segment = np.broadcast_to(np.asarray(segment, dtype=np.int64), pulse_id.shape).astype(np.uint64)
    with np.errstate(over="ignore"):
        h = _mix64(np.full(pulse_id.shape, np.uint64(int(seed) & _MASK64), dtype=np.uint64))
        h = _mix64(h ^ pulse_id)
        return _mix64(h ^ segment)


def pulse_seed(seed: int, pulse_id: int, segment: int = 0) -> int:
    """One waveform's seed: pulse_seeds for a single pulse."""
    return int(pulse_seeds(seed, np.array([int(pulse_id) & _MASK63]), segment)[0])


_MASK63 = (1 << 63) - 1


def _mix64(z: np.ndarray) -> np.ndarray:
    """SplitMix64's step and finaliser on uint64 arrays (arithmetic wraps)."""
    z = z + _GOLDEN
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)
