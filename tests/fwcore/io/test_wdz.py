import numpy as np
import pytest

from fwcore.io.errors import WdzError
from fwcore.io.wdz import decode_packet


def test_wdz_decodes_to_exactly_the_wdp_samples(leica_dir):
    import laspy
    las = laspy.read(leica_dir / "leica_a.las")
    laz = laspy.read(leica_dir / "leica_a.laz")
    wdp = np.fromfile(leica_dir / "leica_a.wdp", np.uint8)
    wdz = np.fromfile(leica_dir / "leica_a.wdz", np.uint8)
    assert np.array_equal(np.asarray(las.gps_time), np.asarray(laz.gps_time))
    for compressed, plain in zip(np.unique(np.asarray(laz.wavepacket_offset)),
                                 np.unique(np.asarray(las.wavepacket_offset))):
        samples = decode_packet(wdz, int(compressed), 256, 8)
        assert np.array_equal(samples, wdp[plain:plain + 256]), f"packet at {compressed}"


def test_wdz_rejects_packets_beyond_the_data(leica_dir):
    wdz = np.fromfile(leica_dir / "leica_a.wdz", np.uint8)
    with pytest.raises(WdzError, match="beyond the end"):
        decode_packet(wdz, wdz.size - 2, 256, 8)
    with pytest.raises(WdzError, match="8- and 16-bit"):
        decode_packet(wdz, 92, 256, 12)
