"""senerf.atomic: atomic writes keep the old file or the new one, leave no temporary behind, and give the
new file the permissions a plain ``open`` would."""

import os
import stat
import sys

import pytest

from senerf.atomic import atomic_write, atomic_write_bytes, atomic_write_text


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX permission bits")
@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_written_file_has_the_mode_open_would_give(tmp_path, umask):
    old = os.umask(umask)
    try:
        atomic_write_text(tmp_path / "metrics.json", "{}")
        with open(tmp_path / "plain.txt", "w") as fh:  # the reference: what open() makes under this umask
            fh.write("{}")
    finally:
        os.umask(old)
    assert _mode(tmp_path / "metrics.json") == _mode(tmp_path / "plain.txt") == 0o666 & ~umask


def test_replaces_content_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "sub" / "a.bin"
    atomic_write_bytes(target, b"old")
    atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new"
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.bin"]


def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    target = tmp_path / "a.txt"
    atomic_write_text(target, "kept")

    def boom(fh):
        fh.write(b"half")
        raise RuntimeError("disk on fire")

    with pytest.raises(RuntimeError, match="disk on fire"):
        atomic_write(target, boom)
    assert target.read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_output_paths_that_cannot_be_created_are_refused_up_front(tmp_path):
    from senerf.atomic import output_file, output_folder
    from senerf.errors import InputError

    (tmp_path / "afile").write_text("x")
    with pytest.raises(InputError,
                       match=r"afile/sub.*cannot be created: .*afile is not a folder; choose another --out"):
        output_folder(tmp_path / "afile" / "sub" / "deeper", "--out")
    with pytest.raises(InputError, match=r"x\.md.*cannot be created: .*afile is not a folder; choose another --into"):
        output_file(tmp_path / "afile" / "x.md", "--into")
    assert output_folder(tmp_path / "new" / "a", "--out") == tmp_path / "new" / "a"  # creatable: fine, not made
    assert not (tmp_path / "new").exists()
