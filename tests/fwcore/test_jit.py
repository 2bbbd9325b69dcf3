import numpy as np

from fwcore._jit import exp2_approx, log2_approx


def test_exp2_matches_numpy_to_its_polynomial_precision():
    x = np.linspace(-60, 100, 20001).astype(np.float32)
    rel = np.abs(exp2_approx(x) / np.exp2(x.astype(np.float64)) - 1)
    assert rel.max() < 1.1e-4


def test_exp2_clamps_below_instead_of_underflowing():
    out = exp2_approx(np.array([-1e4]))
    assert 0 < out[0] < 2e-38


def test_log2_matches_numpy():
    x = np.geomspace(1e-30, 1e30, 20001)
    assert np.abs(log2_approx(x) - np.log2(x)).max() < 1.1e-4


def test_log2_of_zero_is_very_negative_not_nan():
    # a sample exactly at an echo centre has |t - u| = 0
    assert log2_approx(np.array([0.0]))[0] <= -126


def test_kernels_see_inf_and_nan():
    # fastmath without nnan/ninf: an inf sentinel stays infinite inside a kernel
    from numba import njit

    from fwcore._jit import SIMD_JIT

    @njit(**SIMD_JIT)
    def finite(x):
        return np.isfinite(x), np.isnan(x)

    assert finite(np.inf) == (False, False)
    assert finite(np.nan) == (False, True)
    assert finite(1.0) == (True, False)


def test_inlined_searches_are_numpys_including_ties_and_nan():
    from fwcore._jit import searchsorted

    rng = np.random.default_rng(11)
    for n in (0, 1, 2, 7, 60):
        ordered = np.sort(np.round(rng.normal(0, 3, n)))  # rounded: ties
        keys = np.concatenate([ordered, ordered + 0.5, [-np.inf, np.inf, np.nan, -100.0, 100.0]])
        for key in keys:
            assert searchsorted(ordered, key) == np.searchsorted(ordered, key)
            assert searchsorted(ordered, key, right=True) == np.searchsorted(ordered, key, side="right")


def test_kernels_bound_to_libm_cores_give_libm_bits():
    # exp, log and pow over the IEEE cores: every bit of glibc's exported functions, underflow, overflow,
    # subnormals, infinities and NaN included (the engine's results do not move: bench/output_hash.py)
    import ctypes
    import math
    import platform

    import llvmlite.binding as ll
    from numba import njit

    from fwcore._jit import bind_libm_cores

    bound = bind_libm_cores()
    if platform.libc_ver()[0] != "glibc":  # musl, macOS, Windows: nothing is bound, numba's own binding stays
        assert bound == ()
        return
    assert bound == ("exp", "log", "pow")
    libm = ctypes.CDLL("libm.so.6")
    for name in bound:
        getattr(libm, name).restype = ctypes.c_double
        getattr(libm, name).argtypes = [ctypes.c_double] * (2 if name == "pow" else 1)
    core = ctypes.CDLL(None).dlvsym
    core.restype = ctypes.c_void_p
    core.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_char_p]
    assert ll.address_of_symbol("exp") == core(libm._handle, b"__exp_finite", b"GLIBC_2.15")

    @njit(cache=False)  # linked after the binding
    def apply(x, y, out):
        for i in range(x.size):
            out[0, i] = math.exp(x[i])
            out[1, i] = math.log(y[i])
            out[2, i] = math.pow(y[i], x[i] / 50.0)

    rng = np.random.default_rng(3)
    x = np.r_[rng.uniform(-760, 760, 4000), -745.2, -708.4, 0.0, -0.0, 709.8, np.inf, -np.inf, np.nan]
    y = np.r_[rng.uniform(0, 1e3, x.size - 8), 5e-324, 1e-310, 0.0, 1.0, np.inf, 2.0, 3.0, np.nan]
    out = np.empty((3, x.size))
    apply(x, y, out)
    expected = np.array([[libm.exp(a) for a in x], [libm.log(b) for b in y],
                         [libm.pow(b, a / 50.0) for a, b in zip(x, y)]])
    assert np.array_equal(out.view(np.int64), expected.view(np.int64))


def _ulps(got, expected):
    """Distance in units in the last place between float64 arrays of one sign."""
    return np.abs(got.view(np.int64) - expected.view(np.int64))


def _glibc(name, x):
    # libm's, through a kernel as the engine's (bound to glibc's cores: the same bits as its wrappers)
    from numba import njit

    import math

    function = getattr(math, name)

    @njit
    def apply(values, out):
        for i in range(values.size):
            out[i] = function(values[i])

    out = np.empty_like(x)
    apply(x, out)
    return out


def test_vectorizable_exp_is_within_an_ulp_of_libm_and_flushes_below_the_normal_range():
    from fwcore._jit import exp_vectorizable

    rng = np.random.default_rng(0)
    smallest_normal = np.finfo(np.float64).tiny
    lowest = np.log(smallest_normal)
    edges = [-745.0, lowest, np.nextafter(lowest, 0.0), -np.log(2.0) / 2, 0.0, -0.0, 1e-300, -1e-300, 5e-324,
             np.log(2.0) / 2, 10.0, 709.78]
    x = np.concatenate([rng.uniform(-745.0, 10.0, 10**6), rng.uniform(-1.0, 1.0, 10**5), edges])
    expected = _glibc("exp", x)
    normal = expected >= smallest_normal
    assert _ulps(exp_vectorizable(x[normal]), expected[normal]).max() <= 1
    assert (exp_vectorizable(x[~normal]) == 0.0).all() and (~normal).sum() > 1000
    assert exp_vectorizable(np.array([0.0]))[0] == 1.0
    assert exp_vectorizable(np.array([710.0, -1e4])).tolist() == [np.inf, 0.0]


def test_vectorizable_log_is_within_an_ulp_of_libm_over_the_positive_normal_numbers():
    from fwcore._jit import log_vectorizable

    rng = np.random.default_rng(1)
    tiny, largest = np.finfo(np.float64).tiny, np.finfo(np.float64).max
    edges = [tiny, largest, 1.0, np.nextafter(1.0, 2.0), np.nextafter(1.0, 0.0), np.sqrt(0.5), np.sqrt(2.0),
             np.nextafter(np.sqrt(0.5), 0.0), 2.0, 0.5]
    x = np.concatenate([np.exp(rng.uniform(np.log(tiny), np.log(largest), 10**6)), rng.uniform(0.5, 2.0, 10**5),
                        1.0 + rng.uniform(-1e-8, 1e-8, 10**4), edges])
    assert _ulps(log_vectorizable(x), _glibc("log", x)).max() <= 1
    assert log_vectorizable(np.array([1.0, 2.0]))[0] == 0.0


def test_a_loop_over_the_vectorizable_exp_and_log_is_simd():
    import re

    from numba import njit

    from fwcore._jit import exp_ieee, log_ieee

    @njit(error_model="numpy")  # a fresh kernel: cached code cannot be inspected
    def terms(x, out):
        for i in range(x.size):
            out[i] = exp_ieee(-exp_ieee(1.2 * log_ieee(x[i])))

    x = np.linspace(0.1, 5.0, 100)
    out = np.empty_like(x)
    terms(x, out)
    assembly = terms.inspect_asm(terms.signatures[0])
    # a packed float64 multiply: x86's (v)mulpd, AArch64's fmul on .2d lanes
    assert re.search(r"\bv?mulpd\b", assembly) or re.search(r"\bfmul\s+v\d+\.2d", assembly)
    np.testing.assert_allclose(out, np.exp(-(x ** 1.2)), rtol=1e-14)
