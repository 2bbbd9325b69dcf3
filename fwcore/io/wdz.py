"""Decoding of LAStools' compressed waveform packets (`.wdz`).

LASwaveform13writer writes each compressed packet as its first sample raw,
then a LASzip arithmetic-coded stream of the following samples, each coded
by LASzip's IntegerCompressor as the correction from the previous sample
(8- or 16-bit, one context). Models restart with every packet, so a packet
decodes alone from its byte offset. This is a transcription of the narrow
part of LASzip (arithmeticdecoder.cpp, arithmeticmodel.cpp,
integercompressor.cpp) that this needs, in numba; all arithmetic is on
unsigned 32-bit values as in the C++.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.io.errors import WdzError

_MIN_LENGTH = np.uint64(0x01000000)
_MAX_LENGTH = np.uint64(0xFFFFFFFF)
_MASK32 = np.uint64(0xFFFFFFFF)
_BM_LENGTH_SHIFT = 13
_BM_MAX_COUNT = 1 << 13
_DM_LENGTH_SHIFT = 15
_DM_MAX_COUNT = 1 << 15


# A symbol model is a row of int64 state plus arrays: counts, distribution, decoder table.
# state: [symbols, total_count, update_cycle, symbols_until_update, last_symbol, table_size, table_shift]


@njit(**JIT)
def _model_new(symbols):
    table_bits = 0
    table_size = 0
    table_shift = 0
    if symbols > 16:
        table_bits = 3
        while symbols > (1 << (table_bits + 2)):
            table_bits += 1
        table_size = 1 << table_bits
        table_shift = _DM_LENGTH_SHIFT - table_bits
    state = np.zeros(7, dtype=np.int64)
    state[0] = symbols
    state[4] = symbols - 1
    state[5] = table_size
    state[6] = table_shift
    counts = np.ones(symbols, dtype=np.uint64)
    distribution = np.zeros(symbols, dtype=np.uint64)
    table = np.zeros(table_size + 2, dtype=np.int64)
    state[2] = symbols  # update_cycle before the first update
    _model_update(state, counts, distribution, table)
    state[2] = (symbols + 6) >> 1
    state[3] = state[2]
    return state, counts, distribution, table


@njit(**JIT)
def _model_update(state, counts, distribution, table):
    symbols = state[0]
    state[1] += state[2]
    if state[1] > _DM_MAX_COUNT:
        total = 0
        for n in range(symbols):
            counts[n] = (counts[n] + np.uint64(1)) >> np.uint64(1)
            total += counts[n]
        state[1] = total
    scale = np.uint64(0x80000000) // np.uint64(state[1])
    total = np.uint64(0)
    table_size = state[5]
    table_shift = state[6]
    s = 0
    for k in range(symbols):
        distribution[k] = ((scale * total) & _MASK32) >> np.uint64(31 - _DM_LENGTH_SHIFT)
        total += counts[k]
        if table_size > 0:
            w = np.int64(distribution[k] >> np.uint64(table_shift))
            while s < w:
                s += 1
                table[s] = k - 1
    if table_size > 0:
        table[0] = 0
        while s <= table_size:
            s += 1
            table[s] = symbols - 1
    cycle = (5 * state[2]) >> 2
    max_cycle = (symbols + 6) << 3
    state[2] = min(cycle, max_cycle)
    state[3] = state[2]


@njit(**JIT)
def _renormalize(coder, data):
    # coder: [value, length, position]
    while True:
        pos = coder[2]
        byte = np.uint64(data[pos]) if pos < data.size else np.uint64(0)
        coder[2] = pos + 1
        coder[0] = ((coder[0] << np.uint64(8)) | byte) & _MASK32
        coder[1] = (coder[1] << np.uint64(8)) & _MASK32
        if coder[1] >= _MIN_LENGTH:
            break


@njit(**JIT)
def _decode_symbol(coder, data, state, counts, distribution, table):
    value, length = coder[0], coder[1]
    symbols = state[0]
    if state[5] > 0:
        length = length >> np.uint64(_DM_LENGTH_SHIFT)
        dv = value // length
        t = np.int64(dv >> np.uint64(state[6]))
        sym = table[t]
        n = table[t + 1] + 1
        while n > sym + 1:
            k = (sym + n) >> 1
            if distribution[k] > dv:
                n = k
            else:
                sym = k
        x = distribution[sym] * length
        if sym != state[4]:
            y = distribution[sym + 1] * length
        else:
            y = coder[1]
    else:
        x = np.uint64(0)
        sym = 0
        y = length
        length = length >> np.uint64(_DM_LENGTH_SHIFT)
        n = symbols
        k = n >> 1
        while True:
            z = length * distribution[k]
            if z > value:
                n = k
                y = z
            else:
                sym = k
                x = z
            k = (sym + n) >> 1
            if k == sym:
                break
    coder[0] = (value - x) & _MASK32
    coder[1] = (y - x) & _MASK32
    if coder[1] < _MIN_LENGTH:
        _renormalize(coder, data)
    counts[sym] += np.uint64(1)
    state[3] -= 1
    if state[3] == 0:
        _model_update(state, counts, distribution, table)
    return sym


@njit(**JIT)
def _decode_bit(coder, data, bit):
    # bit: [bit_0_count, bit_count, bit_0_prob, update_cycle, bits_until_update]
    x = np.uint64(bit[2]) * (coder[1] >> np.uint64(_BM_LENGTH_SHIFT))
    if coder[0] >= x:
        sym = 1
        coder[0] = (coder[0] - x) & _MASK32
        coder[1] = (coder[1] - x) & _MASK32
    else:
        sym = 0
        coder[1] = x & _MASK32
        bit[0] += 1
    if coder[1] < _MIN_LENGTH:
        _renormalize(coder, data)
    bit[4] -= 1
    if bit[4] == 0:
        bit[1] += bit[3]
        if bit[1] > _BM_MAX_COUNT:
            bit[1] = (bit[1] + 1) >> 1
            bit[0] = (bit[0] + 1) >> 1
            if bit[0] == bit[1]:
                bit[1] += 1
        scale = 0x80000000 // bit[1]
        bit[2] = (bit[0] * scale) >> (31 - _BM_LENGTH_SHIFT)
        bit[3] = min((5 * bit[3]) >> 2, 64)
        bit[4] = bit[3]
    return sym


@njit(**JIT)
def _read_bits(coder, data, bits):
    coder[1] = coder[1] >> np.uint64(bits)
    sym = coder[0] // coder[1]
    coder[0] = (coder[0] - coder[1] * sym) & _MASK32
    if coder[1] < _MIN_LENGTH:
        _renormalize(coder, data)
    return np.int64(sym)


@njit(**JIT)
def _decode_packet(data, start, n_samples, bits, out):
    """Decode one packet at data[start:]; returns the number of bytes consumed."""
    sample_bytes = bits // 8
    first = 0
    for b in range(sample_bytes):
        first |= np.int64(data[start + b]) << (8 * b)
    out[0] = first
    coder = np.zeros(3, dtype=np.uint64)
    pos = start + sample_bytes
    value = np.uint64(0)
    for b in range(4):
        value = (value << np.uint64(8)) | np.uint64(data[pos + b])
    coder[0] = value
    coder[1] = _MAX_LENGTH
    coder[2] = pos + 4
    corr_bits = bits
    corr_range = 1 << bits
    corr_min = -(corr_range // 2)
    bits_high = 8
    # IntegerCompressor models: mBits (corr_bits + 1 symbols), corrector 0 (bit), correctors 1..corr_bits
    m_state, m_counts, m_dist, m_table = _model_new(corr_bits + 1)
    bit = np.array([1, 2, 1 << (_BM_LENGTH_SHIFT - 1), 4, 4], dtype=np.int64)
    c_states = []
    c_counts = []
    c_dists = []
    c_tables = []
    for i in range(1, corr_bits + 1):
        st, cn, ds, tb = _model_new(1 << min(i, bits_high))
        c_states.append(st)
        c_counts.append(cn)
        c_dists.append(ds)
        c_tables.append(tb)
    previous = first
    for s in range(1, n_samples):
        k = _decode_symbol(coder, data, m_state, m_counts, m_dist, m_table)
        if k != 0:
            if k < 32:
                c = _decode_symbol(coder, data, c_states[k - 1], c_counts[k - 1], c_dists[k - 1], c_tables[k - 1])
                if k > bits_high:
                    k1 = k - bits_high
                    c = (c << k1) | _read_bits(coder, data, k1)
                if c >= (1 << (k - 1)):
                    c += 1
                else:
                    c -= (1 << k) - 1
            else:
                c = corr_min
        else:
            c = _decode_bit(coder, data, bit)
        real = previous + c
        if real < 0:
            real += corr_range
        elif real >= corr_range:
            real -= corr_range
        out[s] = real
        previous = real
    return np.int64(coder[2]) - start


def decode_packet(data: np.ndarray, offset: int, n_samples: int, bits: int) -> np.ndarray:
    """The samples of the compressed packet at `offset` of `data` (uint8), as int64."""
    if bits not in (8, 16):
        raise WdzError(f"LAStools compresses 8- and 16-bit waveforms only, not {bits}-bit")
    if offset < 0 or offset + bits // 8 + 4 > data.size:
        raise WdzError(f"compressed packet at byte {offset} lies beyond the end of the data ({data.size} bytes)")
    out = np.zeros(n_samples, dtype=np.int64)
    used = _decode_packet(data, offset, n_samples, bits, out)
    if offset + used > data.size + 4:
        raise WdzError(f"compressed packet at byte {offset} is truncated")
    return out
