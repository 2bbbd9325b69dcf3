"""`fwl info`: headers and indexes, the facts of the samples."""

import json

import numpy as np

from fwcore.io import describe_file, read_pulses
from fwcore.io.writer import write_waveform_las
from pipeline.cli import main


def test_leica_facts(leica_dir):
    for name, fmt, storage in (("leica_a.las", "LAS", "leica_a.wdp"), ("leica_a.laz", "LAZ", "leica_a.wdz")):
        info = describe_file(leica_dir / name)
        assert (info["format"], info["version"], info["point_format"]) == (fmt, "1.3", 4)
        assert (info["points"], info["points_present"], info["pulses"]) == (1125, 1125, 924)
        (d,) = info["descriptors"]
        assert (d["index"], d["bits"], d["samples"], d["spacing_ps"], d["pulses"]) == (1, 8, 256, 2000.0, 924)
        assert storage in info["packets"]
        assert info["gps_time"]["min"] < info["gps_time"]["max"]


def test_descriptor_use_of_a_riegl_style_file(tmp_path, leica_dir):
    leica = read_pulses(leica_dir / "leica_a.las")
    bits = np.where(np.arange(len(leica)) % 4 == 0, 16, 8)
    path = write_waveform_las(tmp_path / "r.las", leica, "las14-wdp", bits,
                              empty_descriptors=[i for i in range(1, 51) if i not in (2, 9)])
    info = describe_file(path)
    used = {d["index"]: d["pulses"] for d in info["descriptors"] if d["pulses"]}
    assert used == {2: 231, 9: 693} or used == {2: 693, 9: 231}
    assert sum(1 for d in info["descriptors"] if d["problem"]) == 48


def test_cli_json_for_several_files(capsys, leica_dir):
    pls = leica_dir.parent / "pulsewaves" / "riegl_example3.pls"
    assert main(["info", "--json", str(leica_dir / "leica_a.las"), str(pls)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [i["format"] for i in out] == ["LAS", "PulseWaves"]
    assert out[1]["pulses"] == 16486 and "EPSG:4978" in out[1]["crs"]["source"]
    assert main(["info", str(pls)]) == 0
    text = capsys.readouterr().out
    assert "descriptor 2: 16485 pulses" in text and "descriptor 3: 1 pulses" in text


def test_cli_names_a_missing_file(capsys, tmp_path):
    assert main(["info", str(tmp_path / "gone.las")]) == 2
    assert "gone.las: no such file" in capsys.readouterr().err


def test_a_gedi_granule_is_described_by_its_beams(leica_dir):
    from fwcore.io import describe_file
    from fwcore.io.info import format_info

    granule = leica_dir.parent / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"
    text = format_info(describe_file(granule))
    assert "GEDI L1B, 164 shots, CRS EPSG:4979" in text
    assert "  BEAM0101: 73 shots, 765-878 samples, 0 stale; lon -44.13661..-44.11382" in text
