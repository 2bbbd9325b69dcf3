"""Each format's first bytes, against the shared files: a LAS file, a PulseWaves pulse and waves file, NEON's CSV and
a GEDI granule (HDF5) each start with theirs, and no file starts with another's."""

from pathlib import Path

from fwcore.io.signatures import HDF5_SIGNATURE, LAS_SIGNATURE, NEON_CSV_HEADER, PULSE_SIGNATURE, WAVES_SIGNATURE

GEDI = Path(__file__).resolve().parents[3] / "examples" / "data" / "gedi"


def test_the_shared_files_start_with_their_formats_signature(leica_dir, neon_dir, pulsewaves_dir):
    files = {LAS_SIGNATURE: leica_dir / "leica_a.las", PULSE_SIGNATURE: pulsewaves_dir / "geolas_example1.pls",
             WAVES_SIGNATURE: pulsewaves_dir / "geolas_example1.wvs",
             NEON_CSV_HEADER: neon_dir / "return_waveforms.csv",
             HDF5_SIGNATURE: GEDI / "GEDI01_B_2019108080338_O01964_T05337_02_003_01_sub.h5"}
    for signature, path in files.items():
        head = path.read_bytes()[:64]
        assert [s for s in files if head.startswith(s)] == [signature], path.name
