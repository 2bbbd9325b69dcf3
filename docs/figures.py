"""The method page's figures, made from the bundled samples by the engine itself: `python docs/figures.py`.

    docs/img/decomposition.png   a Leica and a NEON waveform, the fit, and each echo (kept or spurious)

Run it again when the engine changes; the page shows what it wrote.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from fwcore.engine.config import DecompositionConfig  # noqa: E402
from fwcore.engine.decompose import decompose_batch  # noqa: E402
from fwcore.io import read_pulses  # noqa: E402
from fwcore.io.neon import NEON_SAMPLE_SPACING_PS, read_neon_csv  # noqa: E402
from fwcore.engine.model import generalized_gaussian  # noqa: E402
from fwcore.instrument.pulse import nominal_pulse  # noqa: E402
from fwcore.instrument.width import csv_pulse_fwhm_ps  # noqa: E402
from fwcore.pulses import pulse_waveforms  # noqa: E402
from fwcore.engine.records import WaveformBatch  # noqa: E402
from fwcore.instrument.measure import file_system_pulse  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"


def _panel(ax, samples: np.ndarray, spacing_ps: float, d, title: str) -> None:
    t = np.arange(samples.size) * spacing_ps / 1000.0
    fine = np.linspace(0, samples.size - 1, 8 * samples.size)
    ax.plot(t, samples, ".", color="#888", ms=3, label="samples")
    ax.plot(fine * spacing_ps / 1000.0, d.model(fine), color="#111", lw=1.4, label="fit")
    for k in range(d.amplitude.size):
        kept = d.reject_reason[k] == ""
        ax.plot(fine * spacing_ps / 1000.0,
                d.background + generalized_gaussian(fine, d.amplitude[k], d.position[k], d.sigma[k], d.alpha[k]),
                ls="--" if kept else ":", lw=1.2, color=f"C{k}" if kept else "#d62728",
                label=f"echo {k}" + ("" if kept else f" ({d.reject_reason[k]})"))
    signal = np.flatnonzero(d.model(fine) - d.background > 0.01 * np.ptp(samples))
    if signal.size:  # the part of the packet where the echoes are
        lo, hi = fine[signal[0]], fine[signal[-1]]
        ax.set_xlim(max(0.0, (lo - 0.2 * (hi - lo)) * spacing_ps / 1000.0),
                    min(samples.size - 1, hi + 0.2 * (hi - lo)) * spacing_ps / 1000.0)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("time from the first sample (ns)")
    ax.set_ylabel("digitizer counts")
    ax.legend(fontsize=7, loc="best", framealpha=0.6)


def main() -> None:
    config = DecompositionConfig()
    path = DATA / "leica_als" / "leica_a.las"
    pulses = read_pulses(path)
    system = file_system_pulse(path, 1125, config)
    leica = nominal_pulse(system.fwhm_ps, system.shape_tolerance)  # the generalized Gaussian on Leica's pulse
    result = decompose_batch(pulse_waveforms(pulses, config.seed), config, leica, threads=1)
    echoes = np.diff(result.echo_offsets)
    pick = int(np.flatnonzero(echoes == echoes.max())[0])  # the pulse with the most echoes
    neon = read_neon_csv(DATA / "neon_harvard" / "return_waveforms.csv")
    width = csv_pulse_fwhm_ps(read_neon_csv(DATA / "neon_harvard" / "outgoing_pulses.csv"))
    batch = WaveformBatch.from_waveforms(neon.samples, NEON_SAMPLE_SPACING_PS, np.arange(len(neon.samples)),
                                         neon.valid)
    neon_result = decompose_batch(batch, config, nominal_pulse(width), threads=1)
    n_echoes = np.diff(neon_result.echo_offsets)
    neon_pick = int(np.flatnonzero(n_echoes == np.sort(n_echoes)[-5])[0])
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.6))
    _panel(axes[0], pulses.pulse_samples(pick), float(pulses.sample_spacing_ps[pick]), result.waveform(pick),
           f"Leica sample, pulse {pulses.pulse_id[pick]} (default preset)")
    _panel(axes[1], neon.samples[neon_pick], NEON_SAMPLE_SPACING_PS, neon_result.waveform(neon_pick),
           f"NEON Harvard Forest, waveform {neon.waveform_id[neon_pick]} (default preset)")
    fig.tight_layout()
    out = ROOT / "docs" / "img" / "decomposition.png"
    out.parent.mkdir(exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
