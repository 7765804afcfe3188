"""senerf.atomic: atomic writes keep the old file or the new one, leave no temporary behind, and give the
new file the permissions a plain ``open`` would."""

import os
import stat
import sys
from pathlib import Path

import pytest

from senerf.atomic import atomic_write, atomic_write_bytes, atomic_write_text, output_folder
from senerf.errors import InputError


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
    (tmp_path / "afile").write_text("x")
    with pytest.raises(InputError,
                       match=r"afile/sub.*cannot be created: .*afile is not a folder; choose another --out"):
        output_folder(tmp_path / "afile" / "sub" / "deeper", "--out")
    assert output_folder(tmp_path / "new" / "a", "--out") == tmp_path / "new" / "a"  # creatable: fine, not made
    assert not (tmp_path / "new").exists()


def test_broken_links_on_the_way_are_refused_up_front(tmp_path):
    # before: senerf-fit --out LINK (a link to nothing) died with FileExistsError from mkdir, and senerf-render
    # rendered every frame before its rename onto the link failed
    (tmp_path / "link").symlink_to(tmp_path / "gone")
    for target in (tmp_path / "link", tmp_path / "link" / "sub"):
        with pytest.raises(InputError, match=r"cannot be created: .*link is a broken symbolic link \(to .*gone\); "
                                             r"choose another --out"):
            output_folder(target, "--out")
    (tmp_path / "gone").mkdir()                       # the link now leads somewhere: an ordinary folder
    assert output_folder(tmp_path / "link" / "sub", "--out") == tmp_path / "link" / "sub"


def test_interrupted_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    # Ctrl-C (KeyboardInterrupt is no Exception) while the new content is being written
    target = tmp_path / "a.txt"
    atomic_write_text(target, "kept")

    def interrupted(fh):
        fh.write(b"half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(target, interrupted)
    assert target.read_text() == "kept"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_content_is_on_disk_before_the_rename_and_the_rename_is_synced(tmp_path, monkeypatch):
    """The order a crash-safe write needs: the whole content fsynced in the temporary file, then the rename,
    then the folder fsynced (so the rename itself survives a power cut)."""
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        st = os.fstat(fd)
        events.append(("fsync", "folder" if stat.S_ISDIR(st.st_mode) else st.st_size, st.st_ino))
        real_fsync(fd)

    def replace(src, dst):
        events.append(("replace", os.path.basename(dst)))
        real_replace(src, dst)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    target = tmp_path / "a.bin"
    atomic_write_bytes(target, b"x" * 1000)  # smaller than the write buffer: only a flush puts it in the file
    monkeypatch.undo()
    assert events == [("fsync", 1000, target.stat().st_ino),  # the renamed file is the fsynced temporary
                      ("replace", "a.bin"),
                      ("fsync", "folder", tmp_path.stat().st_ino)]


def test_two_writers_of_one_file_never_share_a_temporary(tmp_path, monkeypatch):
    """A second write of the same file while the first is under way (another process, or the same name
    drawn twice) gets its own temporary: neither clobbers the other's, the last rename wins."""
    import secrets

    tokens = iter(["a" * 12, "a" * 12, "b" * 12])  # the inner write first draws the outer one's name
    monkeypatch.setattr(secrets, "token_hex", lambda nbytes: next(tokens))
    target = tmp_path / "a.txt"

    def outer(fh):
        fh.write(b"outer ")
        atomic_write_text(target, "inner")
        assert target.read_text() == "inner"
        fh.write(b"done")

    atomic_write(target, outer)
    assert target.read_text() == "outer done"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_places_without_write_permission_are_refused_up_front(tmp_path, monkeypatch):
    """A folder (or file) the user may not write is refused naming the path asked for; os.access is faked
    to deny writing there (the tests may run as root, which os.access never denies)."""
    locked, readonly = tmp_path / "locked", tmp_path / "readonly.md"
    locked.mkdir()
    readonly.write_text("x")
    real_access = os.access

    def access(path, mode, *args, **kwargs):
        if Path(path) in (locked, readonly) and mode & os.W_OK:
            return False
        return real_access(path, mode, *args, **kwargs)

    monkeypatch.setattr(os, "access", access)
    cases = [(output_folder, locked, "--out", f"{locked}: is not writable (no write permission); choose another --out"),
             (output_folder, locked / "a" / "b", "--out",
              f"{locked / 'a' / 'b'}: cannot be created in {locked} (no write permission); choose another --out")]
    for check, path, flag, message in cases:
        with pytest.raises(InputError) as info:
            check(path, flag)
        assert str(info.value) == message
