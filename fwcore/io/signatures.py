"""The first bytes of each format's files: fwcore.io.formats tells files apart by them, and each reader checks
its own, so that neither imports the other for them."""

LAS_SIGNATURE = b"LASF"
PULSE_SIGNATURE, WAVES_SIGNATURE = b"PulseWavesPulse\0", b"PulseWavesWaves\0"  # a .pls's and a .wvs's first bytes
NEON_CSV_HEADER = b"waveform_id,n_samples"
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"  # GEDI and LVIS granules: told apart by their groups (Format.sniff)
