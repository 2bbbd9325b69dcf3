"""A file's system pulse, passed to the engine beside the method's settings, and what a user says of it instead.

    fwcore.engine.decompose.decompose_batch(batch, config, pulse)

`DecompositionConfig` holds the method; a `SystemPulse` holds what a file does
not record about its system's pulse and a run measured on its waveforms
(fwcore.instrument.measure): its width, response, shape tolerance, range
offset and, under `--model auto`, the echo model chosen for it. Waveforms with
no file around them take `nominal_pulse`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from fwcore.engine.config import PRESETS, Model
from fwcore.instrument.response import SystemResponse, gaussian_response

DEFAULT_PULSE_FWHM_PS = 4000.0  # where nothing measures the pulse and no one gives it


@dataclasses.dataclass(frozen=True)
class SystemPulse:
    """What a file does not record about its system's pulse, measured on its own waveforms, and how."""

    fwhm_ps: float
    fwhm_source: str  # configured | single returns | estimated from the waveforms | default (unmeasurable)
    shape_tolerance: float  # how far the pulse departs from the model without being another echo (Leica 0.05)
    shape_source: str  # configured | single returns | none measured
    range_offset_ps: float = 0.0  # added to an echo's time to place it where the system places its returns
    range_offset_source: str = "none measured"  # single returns (how many) | none measured
    response: SystemResponse | None = None  # the measured response; None: not measured (the Gaussian of fwhm_ps)
    model: str = ""  # under --model auto, the echo model chosen for the file (system | generalized)
    model_choice: str = ""  # ... and why (fwcore.instrument.measure.choose_system_pulse)

    def echo_model(self, model: Model) -> Model:
        """The echo model a run's `model` setting gives this file: under auto, the one chosen for it."""
        return Model(self.model) if model is Model.AUTO and self.model else model

    def echo_response(self) -> SystemResponse:
        """The echoes' response under the system model: the measured or given one, or the Gaussian of the FWHM."""
        return self.response or gaussian_response(self.fwhm_ps)

    @property
    def response_source(self) -> str:
        return self.response.source if self.response is not None else "none measured"

    def to_dict(self) -> dict:
        return {**dataclasses.asdict(self), "response": self.response.to_dict() if self.response else None}

    @classmethod
    def from_dict(cls, d: dict) -> "SystemPulse":
        response = d.get("response")
        return cls(**{**d, "response": SystemResponse.from_dict(response) if response else None})


def nominal_pulse(fwhm_ps: float = DEFAULT_PULSE_FWHM_PS, shape_tolerance: float = 0.0,
                  response: SystemResponse | None = None) -> SystemPulse:
    """A pulse given, not measured: for waveforms with no file around them (a test's, a simulation's)."""
    return SystemPulse(float(fwhm_ps), "configured", float(shape_tolerance), "configured", response=response)


@dataclasses.dataclass(frozen=True)
class PulseOverrides:
    """What the user says of every file's pulse instead of measuring it (--system-pulse-fwhm-ps,
    --system-response, --shape-tolerance, a preset's): None measures it."""

    fwhm_ps: float | None = None
    response: SystemResponse | None = None
    shape_tolerance: float | None = None

    def __post_init__(self) -> None:
        if self.fwhm_ps is not None and not self.fwhm_ps > 0:
            raise ValueError(f"system pulse FWHM must be positive (ps), not {self.fwhm_ps}; leave "
                             "--system-pulse-fwhm-ps unset to measure it from the data")
        if self.shape_tolerance is not None and not self.shape_tolerance >= 0:
            raise ValueError(f"shape_tolerance must be >= 0, not {self.shape_tolerance}")

    def replace(self, **changes: Any) -> "PulseOverrides":
        return dataclasses.replace(self, **changes)

    @classmethod
    def of_preset(cls, name: str | None) -> "PulseOverrides":
        """What a preset (fwcore.engine.config.PRESETS, its `overrides`) says of every file's pulse; nothing for
        no preset (the paper's constant noise takes its model as exact: a shape tolerance of 0)."""
        return cls(**PRESETS[name].overrides) if name else cls()

    def applied(self, pulse: SystemPulse) -> SystemPulse:
        """A measured pulse with what these say instead (the viewer's refit under another preset)."""
        changes: dict[str, Any] = {}
        if self.fwhm_ps is not None:
            changes.update(fwhm_ps=self.fwhm_ps, fwhm_source="configured")
        if self.shape_tolerance is not None:
            changes.update(shape_tolerance=self.shape_tolerance, shape_source="configured")
        if self.response is not None:
            changes.update(response=self.response)
        return dataclasses.replace(pulse, **changes)

    def to_dict(self) -> dict[str, Any]:
        """As run.json and a run's fingerprint hold them (the names of the command line's options)."""
        return {"system_pulse_fwhm_ps": self.fwhm_ps, "shape_tolerance": self.shape_tolerance,
                "system_response": self.response.to_dict() if self.response else None}

