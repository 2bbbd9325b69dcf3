"""`fwl run` with radiometry: a simulated flight of known reflectances, the RIEGL sample's ranges, the Leica
sample without a trajectory, and the bad inputs that stop a run before anything is decomposed."""

import json
import math

import laspy
import numpy as np
import pyarrow.dataset as ds
import pyarrow.parquet as pq
import pytest

from fwcore.studies.simulate import SceneConfig, SensorConfig
from fwcore.studies.evaluate import evaluate_radiometry
from fwcore.studies.truth import write_flight
from pipeline.cli import main

IN_PROCESS = ["--direct_num_workers=1", "--direct_running_mode=in_memory"]
QUICK = ["--preset", "fast", *IN_PROCESS]
PULSES = 4000


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A radiometric flight (16-bit, reflectances 0.05-0.6, climbing 300 m) with its trajectory and patch."""
    folder = tmp_path_factory.mktemp("flight")
    scene = SceneConfig(radiometry=True, altitude_change_m=300.0, altitude_change_s=PULSES / 100_000.0)
    return write_flight(folder / "sim.las", PULSES, SensorConfig(bits=16), scene, seed=3)


@pytest.fixture(scope="module")
def calibrated(flight, tmp_path_factory):
    out = tmp_path_factory.mktemp("calibrated") / "out"
    code = main(["run", str(flight.las), "--output", str(out), "--formats", "parquet,las",
                 "--trajectory", str(flight.trajectory), "--calibration-reference", str(flight.calibration),
                 "--beam-divergence-mrad", "0.5", *QUICK])
    assert code == 0
    return out


def test_a_calibrated_run_finds_reflectance_and_range_of_the_simulated_truth(calibrated, flight):
    accuracy = evaluate_radiometry(calibrated, flight.truth)
    assert accuracy["extended"] > 1000 and accuracy["with_range"] == 1.0 and accuracy["calibrated"] == 1.0
    assert accuracy["reflectance_error_median"] < 0.03 and accuracy["reflectance_error_p90"] < 0.10
    assert accuracy["range_error_median_cm"] < 2.0


def test_every_calibrated_reflectance_is_finite_and_bounded_and_says_what_it_is(calibrated):
    echoes = ds.dataset(str(calibrated / "echoes")).to_table(
        columns=["kept", "reflectance", "incidence_deg", "reflectance_basis"]).to_pandas()
    kept = echoes[echoes.kept]
    given = kept.reflectance.dropna()
    assert len(given) >= 0.5 * len(kept) and given.between(1e-6, 1.5).all()  # true reflectances 0.05-0.6
    assert kept.incidence_deg.dropna().between(0, 80).all()
    by_incidence = kept.reflectance_basis == "incidence"
    assert kept.incidence_deg[by_incidence].notna().all() and kept.incidence_deg[~by_incidence].isna().all()
    assert set(kept.reflectance_basis) <= {"incidence", "apparent: no plane", "apparent: untrusted plane"}


def test_the_calibration_constant_is_the_simulated_radar_constant(calibrated, flight):
    """The simulator's echoes have energy K rho cos(a) / R^2 (DN x ps); the run's energies are in volts x ps
    (the digitizer gain 0.01 V/DN), so sigma = C R^4 E needs C = pi beta^2 / (K gain)."""
    from fwcore.studies.simulate import RADAR_REFERENCE_RANGE_M, echo_area

    scene, sensor = SceneConfig(), SensorConfig()
    k = scene.radar_amplitude * echo_area(np.array([sensor.pulse_fwhm_ps]), np.array([math.sqrt(2.0)]))[0] \
        * RADAR_REFERENCE_RANGE_M ** 2
    expected = math.pi * (scene.beam_divergence_mrad * 1e-3) ** 2 / (k * sensor.digitizer_gain)
    summary = json.loads((calibrated / "run.json").read_text())["radiometry"]
    found = summary["calibration"]
    assert found["n"] > 100 and found["spread"] < 0.05
    assert found["constant"] == pytest.approx(expected, rel=0.02)
    assert found["source"].startswith("reference patch") and summary["values"] == "calibrated"
    assert summary["calibration_reference"]["reflectance"] == 0.25


def test_a_calibrated_run_resumes_and_says_what_it_used(calibrated, flight, capsys):
    before = (calibrated / "run.json").read_text()
    assert main(["run", str(flight.las), "--output", str(calibrated), "--formats", "parquet,las", "--resume",
                 "--trajectory", str(flight.trajectory), "--calibration-reference", str(flight.calibration),
                 *QUICK]) == 0  # the patch's JSON gives the beam divergence the command line no longer does
    assert "already complete" in capsys.readouterr().out and (calibrated / "run.json").read_text() == before
    summary = json.loads(before)["radiometry"]
    assert summary["calibration_constant"] == summary["calibration"]["constant"]
    settings = json.loads((calibrated / "fwl-output.json").read_text())["settings"]["radiometry"]
    assert settings["trajectory_identity"]["sim.trajectory.csv"]["size"] == flight.trajectory.stat().st_size


def test_the_point_cloud_carries_the_radiometry_as_described_extra_bytes(calibrated):
    las = laspy.read(calibrated / "las" / "sim.las")
    described = {e.name: e.description for e in las.point_format.extra_dimensions}
    assert described["backscatter_cross_section_m2"] == "backscatter cross-section [m2]"
    assert described["reflectance"] == "diffuse reflectance [1]" and described["range_m"].endswith("[m]")
    echoes = ds.dataset(str(calibrated / "echoes")).to_table(
        columns=["kept", "reflectance", "range_m", "radiometry"]).to_pandas()
    kept = echoes[echoes.kept]
    assert len(las.points) == len(kept)
    assert (np.asarray(las.radiometry) == 2).all() and (kept.radiometry == "calibrated").all()
    np.testing.assert_allclose(np.sort(np.asarray(las.range_m)), np.sort(kept.range_m.to_numpy()), rtol=1e-6)


def test_pulsewaves_ranges_come_from_the_scanner_position_in_the_file(tmp_path, pulsewaves_dir):
    out = tmp_path / "riegl"
    assert main(["run", str(pulsewaves_dir / "riegl_example3.pls"), "--output", str(out), "--limit", "600",
                 "--formats", "parquet", *QUICK]) == 0
    echoes = ds.dataset(str(out / "echoes")).to_table().to_pandas()
    kept = echoes[echoes.kept]
    assert kept.range_m.notna().mean() >= 0.99
    assert kept.range_m.between(480, 530).all()  # the Q680 flew ~500 m from these returns
    assert (kept.radiometry == "relative").all() and kept.backscatter_coefficient.notna().all()
    # relative values: C_cal = 1 in km and ns, sigma = (R / km)^4 E / ns with E the energy in digitizer units x ps
    np.testing.assert_allclose(kept.backscatter_cross_section_m2, 1e-15 * kept.range_m ** 4 * kept.energy,
                               rtol=1e-9)
    # of the instrument's energies' scale (it reached 4.2e17 with C = 1 in m and ps), and never 90 deg planes
    assert kept.reflectance.between(0.1, 1e4).all() and kept.incidence_deg.dropna().between(0, 80).all()
    assert set(kept.reflectance_basis) <= {"incidence", "apparent: no plane", "apparent: untrusted plane"}
    planned = json.loads((out / "run.json").read_text())["inputs"][0]["radiometry"]
    assert planned == {"range_source": "scanner position in the file", "why_no_range": None,
                       "beam_divergence_mrad": 0.5, "beam_divergence_source": "file"}
    # fwl view colours the map by the table's reflectance
    from pipeline.view.queries import echoes_in_box
    shown = echoes_in_box(out, "reflectance", None, 1_000_000)
    assert shown["total"] == len(echoes)
    np.testing.assert_allclose(np.sort(np.asarray(shown["value"], float)),
                               np.sort(echoes.reflectance.to_numpy(float)), rtol=1e-6)


def test_a_las_file_without_trajectory_has_null_radiometry_and_says_why(tmp_path, leica_dir, capfd):
    out = tmp_path / "leica"
    assert main(["run", str(leica_dir / "leica_a.las"), "--output", str(out), "--limit", "50",
                 "--formats", "parquet", *QUICK]) == 0
    echoes = pq.read_table(next((out / "echoes").glob("*.parquet"))).to_pandas()
    assert echoes.range_m.isna().all() and echoes.reflectance.isna().all()
    assert (echoes.radiometry == "unavailable").all()
    said = json.loads((out / "run.json").read_text())["inputs"][0]["radiometry"]["why_no_range"]
    assert "give --trajectory" in said and "leica_a.las" in said
    assert capfd.readouterr().out.count("no radiometry: leica_a.las") == 1  # said once


def _shifted(flight, path, column: int, by: float):
    data = np.loadtxt(flight.trajectory, delimiter=",", skiprows=1)
    data[:, column] += by
    np.savetxt(path, data, delimiter=",", header="gps_time,x,y,z", comments="")
    return path


@pytest.mark.parametrize("case, expected", [
    ("late", "are not all within the trajectory"),
    ("elsewhere", "give the trajectory in the file's coordinate reference system"),
    ("adjusted", "cannot be converted back without the GPS week"),
    ("no patch", "no pulse of sim.las reaches the patch"),
    ("dark patch", "the reflectance must be in (0, 1]"),
    ("no divergence", "give --beam-divergence-mrad"),
])
def test_bad_radiometry_input_is_an_error_naming_the_file_and_the_fix(flight, tmp_path, capsys, case, expected):
    trajectory = {"late": lambda: _shifted(flight, tmp_path / "late.csv", 0, 100.0),
                  "elsewhere": lambda: _shifted(flight, tmp_path / "far.csv", 1, 5000.0),
                  "adjusted": lambda: _shifted(flight, tmp_path / "adjusted.csv", 0, 4.5e8)}.get(case, lambda: None)()
    args = ["run", str(flight.las), "--output", str(tmp_path / "out"), "--formats", "parquet",
            "--trajectory", str(trajectory or flight.trajectory), *QUICK]
    if case == "no patch":
        args += ["--calibration-reference", "5000,5000,5100,5100=0.3", "--beam-divergence-mrad", "0.5"]
    if case == "dark patch":
        args += ["--calibration-reference", "0,-90,2,-50=0"]
    if case == "no divergence":  # the patch given on the command line, without the JSON's divergence
        args += ["--calibration-reference", "0,-90,1,-50=0.25"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert expected in err
    if case in ("late", "elsewhere", "adjusted", "no divergence"):
        assert "sim.las" in err and not (tmp_path / "out").exists()  # before the folder is touched
