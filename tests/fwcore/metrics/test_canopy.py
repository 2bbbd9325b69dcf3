"""L2B's formulas on L2B's own rv and rg (to 1e-4, the issue's target), and the ground return's fit on a
waveform made of a known ground return and canopy."""

import numpy as np

from fwcore.metrics.canopy import CanopySettings, GroundPulse, canopy_cover, canopy_energy, extended_gaussian, \
    gap_probability, ground_return, plant_area_index, vertical_profile


def test_l2b_formulas_on_l2b_energies(gedi_beams):
    for b in gedi_beams:
        pgap = gap_probability(b["rv"], b["rg"], b["rhov"] / b["rhog"])
        assert np.abs(pgap - b["pgap_theta"]).max() < 1e-4
        assert np.abs(canopy_cover(pgap, b["l2b_cos_zenith"]) - b["cover"]).max() < 1e-4
        assert np.abs(plant_area_index(pgap, b["l2b_cos_zenith"], b["rossg"], b["omega"]) - b["pai"]).max() < 1e-4


def test_no_energy_is_all_gap_and_no_ground_is_infinite_pai():
    assert gap_probability(0.0, 0.0) == 1.0
    assert np.isinf(plant_area_index(gap_probability(10.0, 0.0), 1.0))


def test_ground_return_recovers_a_known_ground_and_its_canopy():
    x = np.arange(1, 201, dtype=float)
    truth = np.array([5000.0, 120.0, 4.0, 0.15])
    ground = extended_gaussian(truth, x)
    canopy_truth = 300.0 * np.exp(-0.5 * ((x - 80.0) / 6.0) ** 2)
    signal = ground + canopy_truth
    peak = x[np.argmax(ground)] - 1  # the lowest mode, 0-based like L2A's zcross
    model, rg = ground_return(signal, peak, GroundPulse(4.0, 0.01, 0.15, 0.001))
    assert abs(rg / truth[0] - 1) < 0.01
    rv = canopy_energy(signal, model, peak).sum()
    assert abs(rv / canopy_truth.sum() - 1) < 0.02


def test_vertical_profile_puts_the_plant_area_at_its_height():
    heights = np.arange(40.0, -5.0, -0.5)  # 0.5 m samples from 40 m down to below the ground
    canopy = np.where((heights > 20) & (heights < 25), 10.0, 0.0)
    cover_z, pai_z, pavd_z = vertical_profile(heights, canopy, canopy.sum(), 1000.0, 1.0, CanopySettings())
    assert pai_z[0] == pai_z[4] > 0 and pai_z[5] == 0  # all the area between 20 and 25 m
    assert np.isclose(np.trapezoid(pavd_z, dx=5.0), pai_z[0], rtol=0.2)
    assert cover_z[0] == canopy_cover(gap_probability(canopy.sum(), 1000.0), 1.0)


def _plain_fit(x, y, p, lower, upper, iterations):
    """The ground fit as it was written first: every trial's cost summed in full with _extended_gaussian_at, the
    exp and erfc evaluated again for each Jacobian (the reference the fit's reuse of its terms must equal)."""
    import math

    from fwcore.metrics.canopy import _extended_gaussian_at, _solve4

    def cost(q):
        return sum((_extended_gaussian_at(q[0], q[1], q[2], q[3], xi) - yi) ** 2 for xi, yi in zip(x, y))

    def residual_and_jacobian(q):
        a, c, s, g = q
        r2 = math.sqrt(2.0)
        res, jac = np.empty(x.size), np.zeros((x.size, 4))
        for i, xi in enumerate(x):
            e = math.exp(g * (c + 0.5 * g * s * s - xi))
            v = (c + g * s * s - xi) / max(1e-12, r2 * s)
            f = math.erfc(v)
            df = -2.0 / math.sqrt(math.pi) * math.exp(-v * v)
            half = 0.5 * a * g * e
            value = half * f
            if not (math.isfinite(value) and math.isfinite(df * half)):
                res[i] = -y[i]
                continue
            res[i] = value - y[i]
            jac[i] = [0.5 * g * e * f, half * (g * f + df / (r2 * s)),
                      half * (g * g * s * f + df * (-(c - xi) / (r2 * s * s) + g / r2)),
                      0.5 * a * e * f + half * ((c + g * s * s - xi) * f + df * s / r2)]
        return res, jac

    p = p.copy()
    current, damping = cost(p), 1e-3
    for _ in range(iterations):
        res, jac = residual_and_jacobian(p)
        normal, gradient = np.zeros((4, 4)), np.zeros(4)
        for i in range(x.size):  # in the kernel's order: the sums are then the same to the bit
            for j in range(4):
                gradient[j] += jac[i, j] * res[i]
                for m in range(j, 4):
                    normal[j, m] += jac[i, j] * jac[i, m]
        for j in range(4):
            for m in range(j):
                normal[j, m] = normal[m, j]
        for j in range(4):
            if (p[j] <= lower[j] and gradient[j] > 0) or (p[j] >= upper[j] and gradient[j] < 0):
                normal[j, :], normal[:, j], normal[j, j], gradient[j] = 0.0, 0.0, 1.0, 0.0
        improved = False
        for _ in range(30):
            a = normal.copy()
            for j in range(4):
                a[j, j] += damping * max(normal[j, j], 1e-12)
            delta = np.empty(4)
            _solve4(a, -gradient, delta)
            trial = np.minimum(np.maximum(p + delta, lower), upper)
            new = cost(trial)
            if new < current:
                improved = True
                break
            damping *= 10.0
        if not improved:
            break
        relative = (current - new) / max(current, 1e-300)
        p, current, damping = trial, new, max(damping / 10.0, 1e-12)
        if relative < 1e-9:
            break
    return p


def test_the_ground_fit_reusing_its_terms_is_the_plain_fit_to_the_bit():
    from fwcore.metrics.canopy import _fit_extended_gaussian

    rng = np.random.default_rng(7)
    x = np.arange(60.0, 260.0)
    for truth, start in [((5000.0, 120.0, 4.0, 0.15), (900.0, 118.0, 3.8, 0.2)),  # a clean ground: few steps
                         ((800.0, 200.0, 6.0, 1.0), (150.0, 197.0, 5.0, 0.7)),  # LVIS-like, rejected trials
                         ((50.0, 90.0, 3.0, 0.5), (40.0, 92.0, 3.0, 0.5))]:  # a weak ground in noise
        y = np.maximum(extended_gaussian(np.array(truth), x) + rng.normal(0.0, 2.0, x.size), 0.0)
        lower = np.array([-np.inf, start[1] - 4.0, start[2] - 3 * 0.3, start[3] - 3 * 0.1])
        upper = np.array([np.inf, start[1] + 4.0, np.inf, start[3] + 3 * 0.1])
        fitted = _fit_extended_gaussian(x, y, np.array(start), lower, upper, 100)
        assert fitted.tobytes() == _plain_fit(x, y, np.array(start), lower, upper, 100).tobytes()
        assert abs(fitted[0] / truth[0] - 1) < 0.2  # and it is a fit
