"""The format table: what a file is from its first bytes (or its name), and the format that reads it."""

from pathlib import Path

from fwcore.io import formats
from fwcore.io.formats import (EMPTY, FOREIGN_BINARY, FOREIGN_HDF5, GEDI_L1B, LAS, LVIS_L1B, NEON_CSV, PULSEWAVES,
                               TEXT, WAVES_FILE, WDP_FILE, WDZ_FILE, format_of, kind_of, needs_packet_file,
                               packet_file)

DATA = Path(__file__).resolve().parents[3] / "examples" / "data"
BUNDLED = {  # every sample bundled under examples/data, and what it is
    "leica_als/leica_a.las": "a LAS/LAZ file", "leica_als/leica_a.laz": "a LAS/LAZ file",
    "leica_als/leica_a.wdp": WDP_FILE.words, "leica_als/leica_a.wdz": WDZ_FILE.words,
    "gedi/GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5": "a GEDI L1B granule (HDF5)",
    "gedi/GEDI02_A_2019108080338_O01964_T05337_02_001_01_sub.h5": FOREIGN_HDF5.words,
    "gedi/GEDI02_B_2019108080338_O01964_T05337_02_001_01_sub.h5": FOREIGN_HDF5.words,
    "gedi/GEDI04_A_2021150031254_O13948_03_T06447_02_002_01_V002.h5": FOREIGN_HDF5.words,  # biomass: no waveforms
    "neon_harvard/return_waveforms.csv": "a NEON-layout waveform CSV",
    "neon_harvard/outgoing_pulses.csv": "a NEON-layout waveform CSV",
    "neon_harvard/geolocation.csv": "a text file (CSV)", "neon_harvard/system_impulse.csv": "a text file (CSV)",
    "neon_harvard/waveformlidar_gaussian_decomposition.csv": "a text file (CSV)",
    "lvis/LVIS_Mondah_level1b.SPLIT.8.h5": "an LVIS L1B waveform file (HDF5)",
    "lvis/lvis_level1_clip_shared.h5": "an LVIS L1B waveform file (HDF5)",
    "lvis/lvis_level2_clip_shared.txt": "a text file",
    "README.md": "a text file", "pulsewaves/README.md": "a text file",
    **{f"pulsewaves/{name}_example{n}.pls": "a PulseWaves pulse file (.pls)"
       for name, n in (("geolas", 1), ("las13fwf", 1), ("lvis", 1), ("optech", 1), ("riegl", 3))},
    **{f"pulsewaves/{name}_example{n}.wvs": WAVES_FILE.words
       for name, n in (("geolas", 1), ("las13fwf", 1), ("lvis", 1), ("optech", 1), ("riegl", 3))},
}


def test_every_bundled_sample_is_sniffed_to_its_kind():
    on_disk = {str(p.relative_to(DATA)) for p in DATA.rglob("*") if p.is_file()}
    assert on_disk == set(BUNDLED)  # a sample added without its kind here fails
    assert {name: kind_of(DATA / name).words for name in sorted(BUNDLED)} == dict(sorted(BUNDLED.items()))
    assert format_of(DATA / "gedi" / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5") is GEDI_L1B
    assert format_of(DATA / "lvis" / "lvis_level1_clip_shared.h5") is LVIS_L1B


def test_a_file_s_samples_are_found_beside_it(leica_dir, pulsewaves_dir, tmp_path):
    assert packet_file(leica_dir / "leica_a.las") == leica_dir / "leica_a.wdp"
    assert packet_file(pulsewaves_dir / "riegl_example3.pls") == pulsewaves_dir / "riegl_example3.wvs"
    (tmp_path / "alone.txt").write_text("no samples anywhere")
    assert packet_file(tmp_path / "alone.txt") is None
    assert needs_packet_file(leica_dir / "leica_a.las") and needs_packet_file(pulsewaves_dir / "riegl_example3.pls")
    assert not needs_packet_file(DATA / "neon_harvard" / "return_waveforms.csv")


def test_empty_and_plain_text_files_are_told_apart(tmp_path):
    (tmp_path / "empty").write_bytes(b"")
    (tmp_path / "note").write_text("a note\nthen a second line\n")
    assert kind_of(tmp_path / "empty") is EMPTY
    assert kind_of(tmp_path / "note") is TEXT
    assert kind_of(tmp_path / "missing") is formats.UNREADABLE


def test_the_shared_files_are_known_by_their_first_bytes(leica_dir, neon_dir, pulsewaves_dir):
    pls = pulsewaves_dir / "geolas_example1.pls"
    assert (kind_of(leica_dir / "leica_a.las").format, kind_of(pls).format,
            kind_of(neon_dir / "return_waveforms.csv").format) == (LAS, PULSEWAVES, NEON_CSV)
    assert kind_of(neon_dir / "return_waveforms.csv").words == "a NEON-layout waveform CSV"
    assert kind_of(pls.with_suffix(".wvs")) is WAVES_FILE and WAVES_FILE.beside
    assert kind_of(leica_dir / "leica_a.wdp") is WDP_FILE
    assert kind_of(neon_dir / "geolocation.csv").words == "a text file (CSV)"


def test_a_format_is_found_with_one_read_of_the_file(neon_dir, monkeypatch):
    opened = []

    def counting_open(path, *args, **kwargs):
        opened.append(path)
        return open(path, *args, **kwargs)

    monkeypatch.setattr(formats, "open", counting_open, raising=False)
    assert format_of(neon_dir / "return_waveforms.csv") is NEON_CSV
    assert len(opened) == 1


def test_a_pls_is_pulsewaves_by_its_name_and_random_bytes_are_foreign(tmp_path):
    (tmp_path / "empty.pls").write_bytes(b"")
    (tmp_path / "noise.bin").write_bytes(bytes(range(256)))
    assert format_of(tmp_path / "empty.pls") is PULSEWAVES
    assert kind_of(tmp_path / "noise.bin") is FOREIGN_BINARY and format_of(tmp_path / "noise.bin") is LAS
