"""Planning in bounded memory: the bucketed pulse ownership against a plain reference and on real files."""

import tempfile

import laspy
import numpy as np
import pytest

from fwcore.io.las import plan_las_ranges
from fwcore.io.ownership import pulse_ownership


def naive_ownership(keys: np.ndarray, points_per_range: int):
    """The definition, one point at a time: a pulse belongs to the range of its first point."""
    first_point = {}
    for point, key in enumerate(keys.tolist()):
        if key >= 0:
            first_point.setdefault(key, point)
    n_ranges = -(-keys.size // points_per_range)
    pulses = np.bincount([p // points_per_range for p in first_point.values()], minlength=n_ranges)
    straying = [p for p, k in enumerate(keys.tolist())
                if k >= 0 and first_point[k] // points_per_range != p // points_per_range]
    return pulses, np.array(straying, np.int64), np.array([first_point[keys[p]] // points_per_range
                                                           for p in straying], np.int64)


def chunks(keys: np.ndarray, size: int):
    for at in range(0, keys.size, size):
        yield at, keys[at:at + size]


@pytest.mark.parametrize("bucket_points", [10_000, 700, 64, 1])
def test_bucketed_ownership_is_the_definition(bucket_points):
    rng = np.random.default_rng(3)
    # 900 pulses of 1-4 points each, shuffled so that some pulses' points lie far apart; some points have no packet
    pulse_keys = (rng.integers(1, 4, 900).astype(np.int64) << 48) | rng.choice(10**9, 900, replace=False)
    keys = np.repeat(pulse_keys, rng.integers(1, 5, 900))
    keys[rng.random(keys.size) < 0.02] = -1
    rng.shuffle(keys)
    owned = pulse_ownership(chunks(keys, 333), keys.size, 97, bucket_points)
    pulses, straying, stray_owner = naive_ownership(keys, 97)
    np.testing.assert_array_equal(owned.pulses_per_range, pulses)
    np.testing.assert_array_equal(owned.straying, straying)
    np.testing.assert_array_equal(owned.stray_owner, stray_owner)
    assert straying.size > 100  # the shuffle did scatter pulses over ranges
    has = keys >= 0
    np.testing.assert_array_equal(owned.descriptor_points[:4], np.bincount(keys[has] >> 48, minlength=4))
    np.testing.assert_array_equal(owned.descriptor_pulses[:4], np.bincount(np.unique(keys[has]) >> 48, minlength=4))


def test_planning_in_buckets_gives_the_same_ranges(tmp_path, leica_dir, monkeypatch):
    """The Leica file with pulses scattered (returns moved to the end), planned in one bucket and in 64:
    the same ranges, and the buckets' temporary files are gone afterwards."""
    las = laspy.read(leica_dir / "leica_a.las")
    second = np.flatnonzero(np.asarray(las.return_number) >= 2)
    las.points = las.points[np.concatenate([np.delete(np.arange(len(las.points)), second), second])]
    path = tmp_path / "scattered.las"
    las.write(path)
    (tmp_path / "scattered.wdp").write_bytes((leica_dir / "leica_a.wdp").read_bytes())
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    one = plan_las_ranges(path, 100)
    many = plan_las_ranges(path, 100, chunk_points=250, bucket_points=len(las.points) // 64)
    assert many == one
    assert sum(r.n_pulses for r in one) == 924
    index, offset = (np.asarray(las[f]).astype(np.int64) for f in ("wavepacket_index", "wavepacket_offset"))
    _, straying, _ = naive_ownership(index << 48 | offset, 100)
    assert straying.size > 150  # most moved returns now lie in another range than their pulse's first point
    assert sorted(p for r in one for p in r.extra_points) == straying.tolist()
    assert list(scratch.iterdir()) == []
