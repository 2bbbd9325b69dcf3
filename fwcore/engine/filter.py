"""The filter of spurious echoes (the method's section 1.2), applied after the fit.

Spurious echoes stay in the results with their reason: fit accuracy is
computed with every echo, point clouds use the kept ones.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from fwcore._jit import JIT
from fwcore.engine.config import DecompositionConfig

# UNDER_GROUND is set after geolocation (fwcore.plausibility), never by the kernel here
KEPT, WEAK, TOO_CLOSE, OUT_OF_RANGE, TOO_NARROW, TOO_WIDE, UNDER_GROUND = range(7)
_ENGINE = DecompositionConfig()  # filter_echoes's defaults are the engine's own settings
REJECT_REASONS = ("", "weak", "too_close", "out_of_range", "too_narrow", "too_wide", "under_ground")


@njit(**JIT)
def mark_spurious(amplitude, position, width, first, last, pulse_fwhm, noise_sigma, p, reason):
    """Set reason[k] for echoes sorted by position (width = FWHM, same time unit as positions), with the
    filter's settings of p (fwcore.engine.config.KernelParams).

    (1) amplitude below p.min_amplitude_ratio x the largest, or below p.min_snr x
    sigma_noise (a bump of a few counts is not a return); (3) centre outside
    [first, last]; (4) FWHM below p.min_width_factor or above p.max_width_factor x the
    pulse FWHM; then (2) of two echoes closer than p.min_separation_factor x the
    pulse FWHM one is spurious: the earlier is kept when its amplitude is at
    least p.first_echo_ratio x the later's (an unresolved return is reported at its
    first surface), otherwise the weaker, so a weak early bump cannot knock out
    the strong echo after it. p.first_echo_ratio = 1 is the method's rule (the
    weaker goes).
    """
    n = amplitude.size
    largest = 0.0
    for k in range(n):
        largest = max(largest, amplitude[k])
    for k in range(n):
        if amplitude[k] < max(p.min_amplitude_ratio * largest, p.min_snr * noise_sigma) or amplitude[k] <= 0.0:
            reason[k] = WEAK
        elif position[k] < first or position[k] > last:
            reason[k] = OUT_OF_RANGE
        elif width[k] < p.min_width_factor * pulse_fwhm:
            reason[k] = TOO_NARROW
        elif width[k] > p.max_width_factor * pulse_fwhm:
            reason[k] = TOO_WIDE
        else:
            reason[k] = KEPT
    previous = -1
    for k in range(n):
        if reason[k] != KEPT:
            continue
        if previous >= 0 and position[k] - position[previous] < p.min_separation_factor * pulse_fwhm:
            if p.first_echo_ratio * amplitude[k] > amplitude[previous]:
                reason[previous] = TOO_CLOSE
                previous = k
            else:
                reason[k] = TOO_CLOSE
        else:
            previous = k


def filter_echoes(amplitude, position, width, first: float, last: float, pulse_fwhm: float,
                  noise_sigma: float = 0.0, min_snr: float = _ENGINE.min_snr,
                  min_amplitude_ratio: float = _ENGINE.min_amplitude_ratio,
                  min_separation_factor: float = _ENGINE.min_separation_factor,
                  min_width_factor: float = _ENGINE.min_width_factor,
                  max_width_factor: float = _ENGINE.max_width_factor,
                  first_echo_ratio: float = _ENGINE.first_echo_ratio) -> np.ndarray:
    """Reason codes (0 = kept, see REJECT_REASONS) for echoes sorted by position, with the engine's filter (its
    defaults are DecompositionConfig's); the settings are checked as DecompositionConfig checks them."""
    amplitude = np.ascontiguousarray(amplitude, dtype=np.float64)
    position = np.ascontiguousarray(position, dtype=np.float64)
    if np.any(np.diff(position) < 0):
        raise ValueError("echoes must be sorted by position")
    reason = np.zeros(amplitude.size, dtype=np.int8)
    settings = DecompositionConfig(min_snr=min_snr, min_amplitude_ratio=min_amplitude_ratio,
                                   min_separation_factor=min_separation_factor, min_width_factor=min_width_factor,
                                   max_width_factor=max_width_factor, first_echo_ratio=first_echo_ratio)
    mark_spurious(amplitude, position, np.ascontiguousarray(width, dtype=np.float64), float(first), float(last),
                  float(pulse_fwhm), float(noise_sigma), settings.kernel_params(settings.model, 0.0), reason)
    return reason
