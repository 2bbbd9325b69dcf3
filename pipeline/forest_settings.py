"""What a run measures of the forest beside the echoes: one typed record from the command line to the ranges.

`fwl run`, `fwl watch` and the ranges' workers take it whole, so an option added here reaches every worker
(the early ranges' job included) without another argument threaded through each call."""

from __future__ import annotations

import dataclasses

from fwcore.metrics.echo_column import FROM_ECHOES, PULSE_METRICS

SELECTED = "selected"  # --l2a-algorithms: each GEDI shot's L2A-selected algorithm, else 1


@dataclasses.dataclass(frozen=True)
class ForestSettings:
    """--stratum, --l2a-algorithms and --pulse-metrics of `fwl run` / `fwl watch`."""

    stratum: str | None = None  # the L4A biomass model of large-footprint shots whose land cover no L2A names
    l2a_algorithms: str = SELECTED  # GEDI: selected | all | 1..6 (pipeline.plan.file_metric_settings)
    pulse_metrics: str = FROM_ECHOES  # a small footprint's: from its echoes, or FROM_WAVEFORM (its waveform's)

    def checked(self) -> "ForestSettings":
        """The settings with the stratum's canonical name; a ValueError naming what is wrong (an unknown
        stratum lists the strata) before any folder is touched."""
        from fwcore.metrics.biomass import check_stratum

        if self.pulse_metrics not in PULSE_METRICS:
            raise ValueError(f"--pulse-metrics must be one of {', '.join(PULSE_METRICS)}, not {self.pulse_metrics!r}")
        return dataclasses.replace(self, stratum=check_stratum(self.stratum) if self.stratum else None)

    def fingerprint(self) -> dict:
        """What differs from the defaults, for the run's fingerprint: a run with the defaults keeps the
        fingerprint it had before these options existed (so it still resumes)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                if getattr(self, f.name) != f.default}
