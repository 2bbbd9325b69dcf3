"""One place for numba flags, and the vectorizable exp2/log2 the kernels use.

numba has no SVML on this kind of machine and a libm call blocks SIMD, so the
hot model loop uses its own exp2/log2 built from float bit tricks and short
polynomials; LLVM vectorizes them over the samples axis.
The float64 kernels call libm's exp, log and pow through its IEEE cores
(bind_libm_cores, called by the engine before it links its kernels).
"""

from __future__ import annotations

import ctypes
import functools

import numpy as np
from numba import njit, types
from numba.extending import intrinsic

# Kernels are strict IEEE by default: fast-math results depend on what LLVM inlined and fused,
# so a kernel compiled fresh and one loaded from numba's cache by a worker differed in the last
# bits, and a file run alone then gave other rows than in a folder. Only the population
# methods' float32 objective (fwcore.engine.optimizers.objective, never a reported number) takes
# SIMD_JIT: fastmath to reassociate and vectorize, but without nnan/ninf (stumpy's set): with
# them LLVM may assume no inf or NaN exists, and np.isfinite(np.inf) is True inside a kernel.
# error_model="numpy": no zero-division checks, whose exception branch blocks SIMD.
FASTMATH = frozenset({"nsz", "arcp", "contract", "afn", "reassoc"})
JIT = dict(cache=True, nogil=True, error_model="numpy")
SIMD_JIT = dict(JIT, fastmath=set(FASTMATH))
JIT_INLINE = dict(JIT, inline="always")

_F32 = np.float32

# numba binds libm's names to the copies its C helper module was linked against (numba.core.externals): on glibc the
# pre-2.29 entry points, wrappers that test every result for errno's sake around the IEEE core. They were a tenth of
# the engine's CPU on GEDI savanna (perf, 2026-12-07); glibc exports the cores themselves as __exp_finite etc.
_LIBM_CORES = {"exp": "__exp_finite", "log": "__log_finite", "pow": "__pow_finite"}
_LIBM_CORES_VERSION = b"GLIBC_2.15"


@functools.cache
def bind_libm_cores() -> tuple[str, ...]:
    """Bind exp, log and pow in the kernels numba links from now on (compiled or loaded from its cache) to glibc's
    IEEE cores: the same bits as the wrappers numba binds, without their checks. Returns the names bound: none where
    libm is not glibc's (the kernels keep numba's binding). Kernels linked before the call keep theirs."""
    import llvmlite.binding as ll
    from numba.core.registry import cpu_target

    try:
        libm = ctypes.CDLL("libm.so.6")  # glibc's soname (ctypes.util.find_library would run ldconfig)
        dlvsym = ctypes.CDLL(None).dlvsym
    except (OSError, AttributeError, TypeError):  # not glibc (musl, macOS, Windows): numba's binding stays
        return ()
    dlvsym.restype = ctypes.c_void_p
    dlvsym.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p]
    cpu_target.target_context  # numba's own binding, once a process, comes first: it would replace ours
    bound = []
    for name, core in _LIBM_CORES.items():
        address = dlvsym(libm._handle, core.encode(), _LIBM_CORES_VERSION)
        if address:
            ll.add_symbol(name, address)
            bound.append(name)
    return tuple(bound)


@intrinsic
def bits_of_f32(typingctx, x):
    sig = types.int32(types.float32)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int32))

    return sig, codegen


@intrinsic
def _f32_of_bits(typingctx, x):
    sig = types.float32(types.int32)

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float32))

    return sig, codegen


# 2**f on [0, 1): degree-3 Chebyshev fit, relative error 1.0e-4. The population methods' objective
# is all it serves (reported numbers are float64 libm): an echo of an 8-bit digitizer's full scale
# is then off by at most 0.05 DN, a sixth of its quantisation noise, and the two degrees fewer make
# MDE 9% faster (degree 4, 3.6e-6, with degree 5 below: `paper` 58 against 63 pulses/s on Leica).
_E0, _E1, _E2, _E3 = (
    _F32(0.9998967), _F32(0.69639057), _F32(0.22451635), _F32(0.0790857),
)
_LO_EXP = _F32(-126.0)
_ONE = _F32(1.0)
# log2(1 + f) on f in [0, 1): degree-4 Chebyshev fit, absolute error 1.0e-4 (no division, which is slow in SIMD).
_L0, _L1, _L2, _L3, _L4 = (
    _F32(1.00189034e-04), _F32(1.43730211), _F32(-0.672934175), _F32(0.315467596), _F32(-0.0800108761),
)
_MANTISSA = np.int32(0x007FFFFF)
_ONE_BITS = np.int32(0x3F800000)


@njit(**JIT_INLINE)
def fast_exp2(x):
    """2**x for float32 x <= 126 (no upper clamp: the model's exponents stay far below float32's limit),
    clamped below to the normal range, so 2**-1000 is about 1e-38, not 0 or a denormal."""
    x = max(x, _LO_EXP)
    xi = np.floor(x)
    f = x - xi
    p = _E0 + f * (_E1 + f * (_E2 + f * _E3))
    scale = _f32_of_bits((np.int32(xi) + np.int32(127)) << np.int32(23))
    return p * scale


@njit(**JIT_INLINE)
def fast_log2(x):
    """log2(x) for float32 x > 0 (x == 0 gives about -127)."""
    bits = bits_of_f32(x)
    e = _F32((bits >> np.int32(23)) - np.int32(127))
    f = _f32_of_bits((bits & _MANTISSA) | _ONE_BITS) - _ONE
    return e + (_L0 + f * (_L1 + f * (_L2 + f * (_L3 + f * _L4))))


@njit(**JIT)
def _exp2_array(x, out):
    for i in range(x.size):
        out[i] = fast_exp2(x[i])


@njit(**JIT)
def _log2_array(x, out):
    for i in range(x.size):
        out[i] = fast_log2(x[i])


def exp2_approx(x: np.ndarray) -> np.ndarray:
    """The kernels' exp2, over an array (for tests)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    out = np.empty_like(x)
    _exp2_array(x.ravel(), out.ravel())
    return out


def log2_approx(x: np.ndarray) -> np.ndarray:
    """The kernels' log2, over an array of positive values (for tests)."""
    x = np.ascontiguousarray(x, dtype=np.float32)
    out = np.empty_like(x)
    _log2_array(x.ravel(), out.ravel())
    return out


# np.searchsorted, inlined. numba's is a call, and a kernel that calls any function increfs (atomically) every
# array it was given on entry and decrefs it on exit; the model and Jacobian kernels search per echo and per
# LM step. numba's comparisons, NaN sorting last, so every index is numba's.
@njit(**JIT_INLINE)
def searchsorted(ordered, value, right=False):
    """np.searchsorted(ordered, value, side="right" if right else "left"): the first index whose entry is above
    value (right) or not below it (left)."""
    lo, hi = 0, ordered.size
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        entry = ordered[mid]
        if right:
            before = np.isnan(value) or entry <= value
        else:
            before = entry < value or (np.isnan(value) and not np.isnan(entry))
        if before:
            lo = mid + 1
        else:
            hi = mid
    return lo
