"""One place for numba flags, and the vectorizable exp2/log2 the kernels use.

numba has no SVML on this kind of machine and a libm call blocks SIMD, so the
hot model loop uses its own exp2/log2 built from float bit tricks and short
polynomials; LLVM vectorizes them over the samples axis.
The float64 kernels call libm's exp, log and pow through its IEEE cores
(bind_libm_cores, called by the engine before it links its kernels), except the
long records' LM trial and model, which take exp_ieee and log_ieee: float64,
branch-free and strict IEEE, within an ulp of glibc's, so their loops vectorize.
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


def _bitcast(source, target):
    """An intrinsic reading a `source` value's bits as a `target` of the same width (the float bit tricks)."""

    def typer(typingctx, x):
        def codegen(context, builder, signature, args):
            return builder.bitcast(args[0], context.get_value_type(target))

        return target(source), codegen

    typer.__name__ = f"bits_{source}_as_{target}"
    return intrinsic(typer)


bits_of_f32, _f32_of_bits = _bitcast(types.float32, types.int32), _bitcast(types.int32, types.float32)
bits_of_f64, _f64_of_bits = _bitcast(types.float64, types.int64), _bitcast(types.int64, types.float64)


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


# The float64 exp and log of the long records' LM trial: branch-free, so LLVM vectorizes a loop that calls them (a libm
# call blocks SIMD), and strict IEEE (no fast-math), so a vector lane and the scalar remainder give the same bits on any
# machine. Within 1 ulp of glibc's over the trial's arguments (tests/fwcore/test_jit.py measures it).
# Rounding to an integer by adding 1.5 * 2**52: the sum's low mantissa bits are the integer (no float-to-int
# conversion, which AVX2 has not for int64).
_ROUND = 6755399441055744.0
_ROUND_BITS = np.int64(0x4338000000000000)
_INV_LN2 = 1.4426950408889634
# ln 2 in two parts (fdlibm's): n ln2_hi is exact for |n| < 2**20, ln2_lo carries the rest
_LN2_HI = 6.93147180369123816490e-01
_LN2_LO = 1.90821492927058770002e-10
# exp's normal range: below, 0 (the model's terms there are below any digitizer's count by 300 orders)
_EXP_LOWEST = -708.3964185322641
_EXP_HIGHEST = 709.782712893384
# 1 / k! for k = 2 .. 13: Taylor's remainder on |r| <= ln2 / 2 is below 2**-55 of exp(r)
_T2, _T3, _T4, _T5, _T6, _T7 = 1 / 2, 1 / 6, 1 / 24, 1 / 120, 1 / 720, 1 / 5040
_T8, _T9, _T10, _T11, _T12, _T13 = 1 / 40320, 1 / 362880, 1 / 3628800, 1 / 39916800, 1 / 479001600, 1 / 6227020800
_EXPONENT_BIAS = np.int64(1023)
_MANTISSA_BITS = np.int64(52)
# log: fdlibm's (e_log.c) minimax polynomial of the atanh series in s = f / (2 + f), error below 2**-58.45
_LG1, _LG2, _LG3, _LG4 = 6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, \
    2.222219843214978396e-01
_LG5, _LG6, _LG7 = 1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01
# adding this to x's bits carries into the exponent exactly when the mantissa is above sqrt(2) / 2's (0x3fe6a09e...)
_SQRT_HALF_OFFSET = np.int64(0x3FF0000000000000 - 0x3FE6A09E00000000)
_MANTISSA_MASK = np.int64(0x000FFFFFFFFFFFFF)
_SQRT_HALF_HIGH = np.int64(0x3FE6A09E00000000)


@njit(**JIT_INLINE)
def exp_ieee(x):
    """exp(x) for float64 x, within 1 ulp of glibc's where the result is normal; 0 below that range
    (x < -708.396), inf above it. Branch-free: a loop calling it vectorizes. x must not be NaN."""
    y = min(max(x, _EXP_LOWEST), _EXP_HIGHEST)
    shifted = y * _INV_LN2 + _ROUND
    n = shifted - _ROUND  # round(y / ln 2)
    r = (y - n * _LN2_HI) - n * _LN2_LO  # Cody and Waite: |r| <= ln2 / 2, to well below an ulp
    # Estrin's scheme, not Horner's: a loop over lanes is bound by the chain's latency, which this quarters
    r2 = r * r
    r4 = r2 * r2
    q = ((_T2 + _T3 * r) + (_T4 + _T5 * r) * r2) + ((_T6 + _T7 * r) + (_T8 + _T9 * r) * r2) * r4
    q = q + ((_T10 + _T11 * r) + (_T12 + _T13 * r) * r2) * (r4 * r4)
    p = 1.0 + (r + r2 * q)
    # 2**n as two normal powers of two, so n from -1022 to 1024 needs no special case
    k = bits_of_f64(shifted) - _ROUND_BITS
    half = k >> np.int64(1)
    scale1 = _f64_of_bits((half + _EXPONENT_BIAS) << _MANTISSA_BITS)
    scale2 = _f64_of_bits((k - half + _EXPONENT_BIAS) << _MANTISSA_BITS)
    value = p * scale1 * scale2
    value = 0.0 if x < _EXP_LOWEST else value
    return np.inf if x > _EXP_HIGHEST else value


@njit(**JIT_INLINE)
def log_ieee(x):
    """log(x) for positive normal float64 x (fdlibm's algorithm, one division), within 1 ulp of glibc's.
    Branch-free: a loop calling it vectorizes. 0, subnormals, inf and NaN give meaningless finite values."""
    # x = 2**k m with m in [sqrt(1/2), sqrt(2)): the exponent carried up where the mantissa is above sqrt(1/2)'s
    shifted = bits_of_f64(x) + _SQRT_HALF_OFFSET
    k = (shifted >> _MANTISSA_BITS) - _EXPONENT_BIAS
    m = _f64_of_bits((shifted & _MANTISSA_MASK) + _SQRT_HALF_HIGH)
    dk = _f64_of_bits(k + _ROUND_BITS) - _ROUND  # float(k) through the rounding constant (AVX2 has no int64 cvt)
    f = m - 1.0
    hfsq = 0.5 * f * f
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    return s * (hfsq + (t2 + t1)) + dk * _LN2_LO - hfsq + f + dk * _LN2_HI


@njit(error_model="numpy")  # not cached: a function argument's specialisation is not numba-cacheable
def _each(function, x, out):
    for i in range(x.size):
        out[i] = function(x[i])


def _over_array(function, x: np.ndarray, dtype) -> np.ndarray:
    """One of the kernels' scalar functions over an array, as a kernel calls it (for tests)."""
    x = np.ascontiguousarray(x, dtype=dtype)
    out = np.empty_like(x)
    _each(function, x.ravel(), out.ravel())
    return out


def exp_vectorizable(x: np.ndarray) -> np.ndarray:
    """The kernels' float64 exp (exp_ieee), over an array (for tests)."""
    return _over_array(exp_ieee, x, np.float64)


def log_vectorizable(x: np.ndarray) -> np.ndarray:
    """The kernels' float64 log (log_ieee), over an array of positive normal values (for tests)."""
    return _over_array(log_ieee, x, np.float64)


def exp2_approx(x: np.ndarray) -> np.ndarray:
    """The kernels' exp2, over an array (for tests)."""
    return _over_array(fast_exp2, x, np.float32)


def log2_approx(x: np.ndarray) -> np.ndarray:
    """The kernels' log2, over an array of positive values (for tests)."""
    return _over_array(fast_log2, x, np.float32)


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
