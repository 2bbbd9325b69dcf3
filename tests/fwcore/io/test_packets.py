import numpy as np
import pytest

from fwcore.io.descriptors import WaveformDescriptor
from fwcore.io.errors import PacketError
from fwcore.io.packets import PacketStore


def _store(tmp_path, payload: bytes) -> tuple[PacketStore, np.ndarray]:
    path = tmp_path / "p.wdp"
    path.write_bytes(bytes(60) + payload)
    store = PacketStore(path, 0, False)
    return store, store.open()


@pytest.mark.parametrize("bits,dtype", [(8, "<u1"), (12, "<u2"), (16, "<u2"), (24, "<u4"), (32, "<u4")])
def test_sample_widths_are_read_from_their_containers(tmp_path, bits, dtype):
    values = np.array([0, 1, 2 ** bits - 1, 1234 % 2 ** bits], dtype=np.uint64)
    store, data = _store(tmp_path, values.astype(dtype).tobytes())
    d = WaveformDescriptor(1, bits, 0, 4, 1000.0, 1.0, 0.0)
    np.testing.assert_array_equal(store.read(data, d, 60, d.packet_bytes), values.astype(float))


def test_packet_smaller_than_its_descriptor(tmp_path):
    store, data = _store(tmp_path, bytes(100))
    d = WaveformDescriptor(1, 16, 0, 40, 1000.0, 1.0, 0.0)
    with pytest.raises(PacketError, match="less than descriptor 1's 40 samples x 2 bytes"):
        store.read(data, d, 60, 20)
