"""Listing what the viewer serves while runs are being written."""

import shutil
from pathlib import Path

from pipeline.view.catalog import files_under


def test_a_folder_that_vanishes_while_it_is_listed_is_skipped(tmp_path):
    (tmp_path / "first.las").write_bytes(b"")
    for sub in ("a", "b"):  # a running job's temporary folders
        (tmp_path / sub).mkdir()
        (tmp_path / sub / "part.parquet").write_bytes(b"")
    walk = files_under(tmp_path)
    assert next(walk) == tmp_path / "first.las"  # the top folder is read: a/ and b/ are known
    shutil.rmtree(tmp_path / "a")
    shutil.rmtree(tmp_path / "b")  # the job finished and removed them
    assert list(walk) == []


def test_every_file_and_link_is_listed_and_a_linked_folder_is_not_entered(tmp_path):
    (tmp_path / "view" / "deep" / "er").mkdir(parents=True)
    (tmp_path / "view" / "deep" / "er" / "x.pls").write_bytes(b"")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "y.las").write_bytes(b"")
    (tmp_path / "view" / "y.las").symlink_to(tmp_path / "elsewhere" / "y.las")
    (tmp_path / "view" / "out").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    listed = sorted(p.relative_to(tmp_path / "view") for p in files_under(tmp_path / "view"))
    assert listed == [Path("deep/er/x.pls"), Path("y.las")]
