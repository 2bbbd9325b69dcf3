"""Radiometry: every echo's range to the scanner, its incidence, backscatter cross-section, backscatter
coefficient and diffuse reflectance (Wagner 2006, 2010), calibrated where the run is given how.

    range:      the scanner's optical centre in the file (PulseWaves) or a trajectory at the pulse's GPS time
                (fwcore.radiometry.trajectory)
    incidence:  the angle between the beam and a plane through the echo's neighbouring kept echoes
    sigma       = C_cal R^4 E                (E the echo's energy: amplitude x width, the engine's area)
    gamma       = 4 sigma / (pi R^2 beta^2)  (beta the beam divergence, full angle at 1/e^2)
    rho         = gamma / (4 cos alpha)      (a Lambertian target that fills the footprint)

C_cal comes from a reference patch of known reflectance (its single returns, by their median), or is given;
without either it is 1 with the range in km and the energy per ns (1e-15 in m and ps: values of a sane scale,
not 1e17) and every value is relative, and said so. An incidence is used only from a trusted plane (within 80
degrees of facing the beam, its tilt uncertain by less than 5% of cos alpha); elsewhere the reflectance is the
apparent one (cos alpha = 1), or null, and `reflectance_basis` says which and why. Plain functions over numpy arrays: the
pipeline's Geolocate stage and the calibration's pre-pass call `echo_radiometry`.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from fwcore.radiometry.errors import RadiometryError
from fwcore.radiometry.trajectory import Trajectory

# one ps of echo time is this much range (two-way, in air): a file whose beam steps differ is not in metres
RANGE_M_PER_PS = 299702547.0e-12 / 2.0
METRIC_STEP_TOLERANCE = 0.05
CALIBRATED, RELATIVE, UNAVAILABLE = "calibrated", "relative", "unavailable"
# C_cal = 1 with R in km and E in units x ns: a relative value of the same scale as the instrument's energies
RELATIVE_CONSTANT = 1e-15
# beyond 80 deg 1/cos alpha exceeds 5.8 and grows by tan(alpha) = 10% a degree of the plane's error; a plane that
# nearly holds the beam is as likely fitted along it (echoes of a few pulses at a step or in a crown) as seen edge-on
MAX_INCIDENCE_DEG = 80.0
# a plane whose tilt uncertainty moves cos alpha by more than this (5%) is ill-conditioned for the reflectance
MAX_COSINE_ERROR = 0.05
# why an echo's reflectance is what it is (the column reflectance_basis)
BY_INCIDENCE = "incidence"
APPARENT_NO_PLANE = "apparent: no plane"
APPARENT_UNTRUSTED = "apparent: untrusted plane"
NULL_NO_RANGE = "null: no range"
NULL_NO_ENERGY = "null: no energy"
NULL_NO_DIVERGENCE = "null: no beam divergence"


# ---------------------------------------------------------------- options

@dataclasses.dataclass(frozen=True)
class CalibrationReference:
    """A patch of the scene of known diffuse reflectance (asphalt, a reference tarp): its single returns give C_cal."""

    bbox: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax in the inputs' CRS
    reflectance: float
    beam_divergence_mrad: float | None = None  # the divergence it was flown with, where its JSON says (fwl simulate)

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        xmin, ymin, xmax, ymax = self.bbox
        return (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)


def parse_calibration_reference(text: str) -> CalibrationReference:
    """"xmin,ymin,xmax,ymax=REFLECTANCE", or a JSON file {"bbox": [xmin, ymin, xmax, ymax], "reflectance": R}
    (what `fwl simulate` writes beside its flight)."""
    where = f"--calibration-reference {text!r}"
    if "=" not in text and Path(text).is_file():
        try:
            value = json.loads(Path(text).read_text())
            bbox, reflectance = value["bbox"], value["reflectance"]
            divergence = value.get("beam_divergence_mrad")
        except (OSError, ValueError, KeyError, TypeError) as err:
            raise RadiometryError(f"{text}: not a calibration reference ({err}); it needs "
                                  '{"bbox": [xmin, ymin, xmax, ymax], "reflectance": R}') from None
    else:
        box, _, value = text.partition("=")
        divergence = None
        try:
            bbox, reflectance = [float(v) for v in box.split(",")], float(value)
        except ValueError:
            raise RadiometryError(f"{where}: write it as xmin,ymin,xmax,ymax=REFLECTANCE (numbers), or give a "
                                  "JSON file with bbox and reflectance") from None
    if len(bbox) != 4 or not all(math.isfinite(float(v)) for v in bbox):
        raise RadiometryError(f"{where}: the patch needs four finite numbers xmin,ymin,xmax,ymax")
    xmin, ymin, xmax, ymax = (float(v) for v in bbox)
    if xmin >= xmax or ymin >= ymax:
        raise RadiometryError(f"{where}: the patch is empty (xmin < xmax and ymin < ymax are needed)")
    reflectance = float(reflectance)
    if not (math.isfinite(reflectance) and 0.0 < reflectance <= 1.0):
        raise RadiometryError(f"{where}: the reflectance must be in (0, 1] (a diffuse reflectance, 0.25 for 25%), "
                              f"not {reflectance:g}")
    return CalibrationReference((xmin, ymin, xmax, ymax), reflectance,
                                float(divergence) if divergence is not None else None)


@dataclasses.dataclass(frozen=True)
class RadiometryConfig:
    """How a run computes radiometry: one object passed down to the stages."""

    trajectory: str | None = None  # SBET (binary) or CSV gps_time,x,y,z in the inputs' CRS, for LAS inputs
    calibration_reference: CalibrationReference | None = None
    calibration_constant: float | None = None  # C_cal: given, or found on the reference patch before the run
    calibration_source: str = "none"  # given | reference patch (n single returns) | none
    beam_divergence_mrad: float | None = None  # full angle at 1/e^2; overrides the file's
    plane_neighbours: int = 10  # kept echoes that make an echo's local plane
    plane_radius_m: float = 5.0  # the farthest neighbour that counts
    plane_rms_m: float = 0.10  # the plane's RMS misfit above which there is no plane (vegetation, edges)

    def __post_init__(self) -> None:
        if self.calibration_constant is not None and not (math.isfinite(self.calibration_constant)
                                                          and self.calibration_constant > 0):
            raise RadiometryError(f"--calibration-constant must be a positive number, not {self.calibration_constant}")
        if self.beam_divergence_mrad is not None and not (math.isfinite(self.beam_divergence_mrad)
                                                          and self.beam_divergence_mrad > 0):
            raise RadiometryError(f"--beam-divergence-mrad must be a positive number, not {self.beam_divergence_mrad}")
        if self.plane_neighbours < 3 or self.plane_radius_m <= 0 or self.plane_rms_m <= 0:
            raise RadiometryError("a local plane needs at least 3 neighbours, a positive radius and tolerance")

    @property
    def calibrated(self) -> bool:
        return self.calibration_constant is not None

    def constant(self) -> float:
        return self.calibration_constant if self.calibration_constant is not None else RELATIVE_CONSTANT

    def to_dict(self) -> dict:
        value = dataclasses.asdict(self)
        if self.calibration_reference is not None:  # as JSON keeps it: a fingerprint compares with its manifest copy
            value["calibration_reference"] = {**dataclasses.asdict(self.calibration_reference),
                                              "bbox": list(self.calibration_reference.bbox)}
        return value

    @classmethod
    def from_dict(cls, value: dict) -> "RadiometryConfig":
        value = dict(value)
        if value.get("calibration_reference"):
            ref = value["calibration_reference"]
            value["calibration_reference"] = CalibrationReference(tuple(ref["bbox"]), ref["reflectance"],
                                                                  ref.get("beam_divergence_mrad"))
        return cls(**value)


# ---------------------------------------------------------------- ranges, planes, the radar equation

def metric_beam(direction: np.ndarray) -> np.ndarray:
    """Whether each pulse's direction steps the distance light travels (two-way) in a ps: coordinates in metres.
    Geographic degrees or feet are not, and get no range."""
    step = np.linalg.norm(direction, axis=1)
    return np.abs(step / RANGE_M_PER_PS - 1.0) < METRIC_STEP_TOLERANCE


def local_plane_normals(xyz: np.ndarray, neighbours: int, radius_m: float, max_rms_m: float) -> np.ndarray:
    """Unit normals (n, 3) of planes fitted to each point and its nearest `neighbours` within `radius_m`; NaN where
    fewer than 3 neighbours are that close or the plane's RMS misfit exceeds `max_rms_m` (no plane: vegetation,
    edges)."""
    return local_planes(xyz, neighbours, radius_m, max_rms_m)[0]


def local_planes(xyz: np.ndarray, neighbours: int, radius_m: float, max_rms_m: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """local_plane_normals, and each plane's tilt uncertainty (radians, 1 sigma, about its narrower axis):
    sqrt(misfit variance / (points x variance along that axis)), as for the slope of a line fitted to them."""
    from scipy.spatial import cKDTree

    n = len(xyz)
    normals = np.full((n, 3), np.nan)
    tilt = np.full(n, np.nan)
    finite = np.all(np.isfinite(xyz), axis=1)
    rows = np.flatnonzero(finite)
    if rows.size < 4:
        return normals, tilt
    points = xyz[rows]
    origin = points.mean(axis=0)  # numerically kinder than UTM or ECEF magnitudes
    points = points - origin
    k = min(neighbours + 1, rows.size)
    distance, index = cKDTree(points).query(points, k=k, distance_upper_bound=radius_m)
    present = np.isfinite(distance)
    count = present.sum(axis=1)
    gathered = points[np.where(present, index, 0)] * present[..., None]
    centre = gathered.sum(axis=1) / count[:, None]
    offsets = (gathered - centre[:, None, :]) * present[..., None]
    covariance = np.einsum("nki,nkj->nij", offsets, offsets) / count[:, None, None]
    values, vectors = np.linalg.eigh(covariance)
    rms = np.sqrt(np.maximum(values[:, 0], 0.0))
    ok = (count >= 4) & (rms <= max_rms_m) & (values[:, 1] > 4.0 * values[:, 0])  # a plane, not a line
    normals[rows[ok]] = vectors[ok, :, 0]
    tilt[rows[ok]] = np.sqrt(np.maximum(values[ok, 0], 0.0) / (count[ok] * values[ok, 1]))
    return normals, tilt


def incidence_angle(normals: np.ndarray, beam: np.ndarray) -> np.ndarray:
    """Radians between the beam (unit, either sense) and the surface normal; NaN where there is no plane."""
    cosine = np.abs(np.einsum("ij,ij->i", normals, beam))
    return np.arccos(np.clip(cosine, 0.0, 1.0))


def trusted_incidence(incidence_rad: np.ndarray, tilt_rad: np.ndarray | None = None) -> np.ndarray:
    """The incidence where its plane can be trusted, NaN elsewhere: at most MAX_INCIDENCE_DEG, and where the plane's
    tilt uncertainty moves cos alpha by at most MAX_COSINE_ERROR (relative: tan alpha x tilt)."""
    with np.errstate(invalid="ignore"):
        ok = incidence_rad <= math.radians(MAX_INCIDENCE_DEG)
        if tilt_rad is not None:
            ok &= np.tan(incidence_rad) * tilt_rad <= MAX_COSINE_ERROR
        return np.where(ok, incidence_rad, np.nan)


def backscatter_cross_section(energy: np.ndarray, range_m: np.ndarray, constant: float) -> np.ndarray:
    """sigma = C_cal R^4 E (m^2 when C_cal is calibrated)."""
    return constant * range_m ** 4 * energy


def backscatter_coefficient(cross_section: np.ndarray, range_m: np.ndarray, beam_divergence_rad: float) -> np.ndarray:
    """gamma = 4 sigma / (pi R^2 beta^2): the cross-section per illuminated area (Wagner 2010)."""
    return 4.0 * cross_section / (math.pi * range_m ** 2 * beam_divergence_rad ** 2)


def diffuse_reflectance(coefficient: np.ndarray, incidence_rad: np.ndarray) -> np.ndarray:
    """rho = gamma / (4 cos alpha), alpha 0 where unknown (the apparent reflectance, as at normal incidence)."""
    return coefficient / (4.0 * np.cos(np.where(np.isfinite(incidence_rad), incidence_rad, 0.0)))


@dataclasses.dataclass(frozen=True)
class EchoGeometry:
    """What radiometry needs of a range's echoes, in the engine's echo order."""

    xyz: np.ndarray  # (m, 3) geolocated echoes
    beam: np.ndarray  # (m, 3) unit direction of each echo's pulse, away from the scanner
    range_m: np.ndarray  # NaN where unknown
    energy: np.ndarray  # the echo's area in the instrument's linear units x ps
    kept: np.ndarray  # bool


def echo_ranges(xyz: np.ndarray, echo_time_ps: np.ndarray, direction: np.ndarray, gps_time: np.ndarray,
                sensor_location_ps: np.ndarray | None, trajectory: Trajectory | None,
                file_time_system: str) -> np.ndarray:
    """Each echo's range to the scanner (m): from the scanner's place on the beam where the file records it
    (PulseWaves), else from the trajectory at the pulse's GPS time; NaN where neither, or the file's
    coordinates are not metres. Arrays per echo (its pulse's values repeated)."""
    range_m = np.full(len(xyz), np.nan)
    metric = metric_beam(direction)
    if sensor_location_ps is not None:
        along = np.abs(echo_time_ps - sensor_location_ps) * np.linalg.norm(direction, axis=1)
        range_m = np.where(np.isfinite(sensor_location_ps), along, np.nan)
    if trajectory is not None:
        missing = ~np.isfinite(range_m)
        if missing.any():
            sensor = trajectory.positions(gps_time[missing], file_time_system)
            range_m[missing] = np.linalg.norm(xyz[missing] - sensor, axis=1)
    return np.where(metric, range_m, np.nan)


def echo_radiometry(geometry: EchoGeometry, config: RadiometryConfig, beam_divergence_mrad: float | None
                    ) -> dict[str, np.ndarray]:
    """Per echo: range_m, incidence_deg (kept echoes with a trusted local plane), backscatter_cross_section_m2,
    backscatter_coefficient, reflectance, the flag radiometry (calibrated | relative | unavailable) and
    reflectance_basis (incidence | apparent: why | null: why). Every value is finite and positive, or NaN: no
    range, no energy, or (coefficient and reflectance) no beam divergence."""
    m = len(geometry.range_m)
    normals, tilt = np.full((m, 3), np.nan), np.full(m, np.nan)
    kept = np.flatnonzero(geometry.kept & np.isfinite(geometry.range_m))
    normals[kept], tilt[kept] = local_planes(geometry.xyz[kept], config.plane_neighbours, config.plane_radius_m,
                                             config.plane_rms_m)
    fitted = incidence_angle(normals, geometry.beam)
    incidence = trusted_incidence(fitted, tilt)
    with np.errstate(invalid="ignore", over="ignore"):
        sigma = backscatter_cross_section(geometry.energy, geometry.range_m, config.constant())
        ranged = np.isfinite(geometry.range_m) & (geometry.range_m > 0)
        has = ranged & np.isfinite(sigma) & (sigma > 0)
        sigma = np.where(has, sigma, np.nan)
        if beam_divergence_mrad:
            gamma = backscatter_coefficient(sigma, geometry.range_m, beam_divergence_mrad * 1e-3)
            rho = diffuse_reflectance(gamma, incidence)
        else:
            gamma = rho = np.full(m, np.nan)
    basis = np.select([~ranged, ~has, np.isnan(rho), np.isfinite(incidence), np.isfinite(fitted)],
                      [NULL_NO_RANGE, NULL_NO_ENERGY, NULL_NO_DIVERGENCE, BY_INCIDENCE, APPARENT_UNTRUSTED],
                      APPARENT_NO_PLANE).astype(object)
    flag = np.where(has, CALIBRATED if config.calibrated else RELATIVE, UNAVAILABLE)
    return {"range_m": np.where(ranged, geometry.range_m, np.nan), "incidence_deg": np.degrees(incidence),
            "backscatter_cross_section_m2": sigma, "backscatter_coefficient": gamma, "reflectance": rho,
            "radiometry": flag, "reflectance_basis": basis}


def calibration_samples(radiometry: dict[str, np.ndarray], xyz: np.ndarray, single: np.ndarray,
                        reference: CalibrationReference, beam_divergence_mrad: float) -> np.ndarray:
    """C_cal per echo of the reference patch: single returns inside it with a range and a local plane, whose
    R^4 E (their relative cross-section over RELATIVE_CONSTANT) times C_cal must equal pi rho R^2 beta^2 cos alpha
    (a Lambertian extended target)."""
    inside = (single & reference.contains(xyz[:, 0], xyz[:, 1]) & np.isfinite(radiometry["incidence_deg"])
              & np.isfinite(radiometry["backscatter_cross_section_m2"]))
    r = radiometry["range_m"][inside]
    alpha = np.radians(radiometry["incidence_deg"][inside])
    beta = beam_divergence_mrad * 1e-3
    expected = math.pi * reference.reflectance * r ** 2 * beta ** 2 * np.cos(alpha)
    return expected / (radiometry["backscatter_cross_section_m2"][inside] / RELATIVE_CONSTANT)


@dataclasses.dataclass(frozen=True)
class Calibration:
    """C_cal found on a reference patch: the median of its single returns' values, how many, and their spread."""

    constant: float
    n: int
    spread: float  # robust relative spread: 1.4826 MAD / median
    p10: float
    p90: float

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def calibration_from_samples(samples: np.ndarray) -> Calibration:
    samples = samples[np.isfinite(samples) & (samples > 0)]
    if samples.size == 0:
        raise RadiometryError("no single return of the reference patch has a range and a local plane")
    median = float(np.median(samples))
    mad = float(np.median(np.abs(samples - median)))
    return Calibration(median, int(samples.size), 1.4826 * mad / median, float(np.percentile(samples, 10)),
                       float(np.percentile(samples, 90)))
