"""Atomic, durable writes and safe reads (issue 12: umask, fsync, temp files, signals, kill -9)."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from posturemap.io import bvh, fileio
from posturemap import sample
from posturemap.io.fileio import TEMP_PREFIX, write_bytes_atomic

REPO = Path(__file__).resolve().parent.parent


def temps(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(TEMP_PREFIX)]


@pytest.mark.parametrize("mask", [0o022, 0o002, 0o077])
def test_issue12_new_file_mode_follows_the_umask(tmp_path, mask):
    old = os.umask(mask)
    try:
        assert fileio.umask() == mask
        write_bytes_atomic(tmp_path / "out.bvh", b"data")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "out.bvh").stat().st_mode) == 0o666 & ~mask


def test_issue12_file_and_folder_are_fsynced_before_and_after_the_rename(tmp_path, monkeypatch):
    events = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd):
        kind = "folder" if stat.S_ISDIR(os.fstat(fd).st_mode) else "file"
        events.append(("fsync", kind))
        real_fsync(fd)

    def replace(a, b):
        events.append(("replace", None))
        real_replace(a, b)

    monkeypatch.setattr(os, "fsync", fsync)
    monkeypatch.setattr(os, "replace", replace)
    write_bytes_atomic(tmp_path / "out.bvh", b"data")
    assert events == [("fsync", "file"), ("replace", None), ("fsync", "folder")]
    assert (tmp_path / "out.bvh").read_bytes() == b"data"


@pytest.mark.parametrize("fail", ["write", "fsync", "replace"])
def test_issue12_no_temp_file_after_an_error(tmp_path, monkeypatch, fail):
    target = tmp_path / "out.bvh"
    target.write_bytes(b"old")

    def boom(*args, **kwargs):
        raise OSError(28, "No space left on device")

    if fail == "write":
        monkeypatch.setattr(os, "fchmod", boom)
    else:
        monkeypatch.setattr(os, fail, boom)
    with pytest.raises(OSError):
        write_bytes_atomic(target, b"new")
    monkeypatch.undo()
    assert target.read_bytes() == b"old"
    assert temps(tmp_path) == []


def test_keyboard_interrupt_removes_the_temp_file(tmp_path, monkeypatch):
    def interrupted(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupted)
    with pytest.raises(KeyboardInterrupt):
        write_bytes_atomic(tmp_path / "out.bvh", b"new")
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


_SIGNAL_SCRIPT = textwrap.dedent("""
    import os, signal, sys, time
    # Ctrl-C as in a terminal, even when the tests run in a background job (which starts every
    # child with SIGINT ignored, so that Python never raises KeyboardInterrupt).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    from posturemap.io import fileio
    real = os.fsync
    def slow(fd):
        print("writing", flush=True)
        time.sleep(30)
    os.fsync = slow
    fileio.write_bytes_atomic(sys.argv[1], b"new" * 1000)
""")


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_issue12_signal_during_write_removes_the_temp_file(tmp_path, sig):
    target = tmp_path / "out.bvh"
    target.write_bytes(b"old")
    proc = subprocess.Popen([sys.executable, "-c", _SIGNAL_SCRIPT, str(target)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "writing"
    assert len(temps(tmp_path)) == 1  # the temp file exists while writing
    proc.send_signal(sig)
    proc.wait(20)
    assert proc.returncode != 0
    assert target.read_bytes() == b"old"
    assert temps(tmp_path) == []
    proc.stdout.close()
    proc.stderr.close()


def test_sigterm_handler_is_restored_after_the_write(tmp_path):
    before = signal.getsignal(signal.SIGTERM)
    write_bytes_atomic(tmp_path / "x", b"1")
    assert signal.getsignal(signal.SIGTERM) is before


def test_write_from_a_thread_works(tmp_path):
    import threading

    t = threading.Thread(target=write_bytes_atomic, args=(tmp_path / "t.bin", b"abc"))
    t.start()
    t.join()
    assert (tmp_path / "t.bin").read_bytes() == b"abc"


def test_bvh_write_bytes_atomic_is_still_importable():
    assert bvh.write_bytes_atomic is write_bytes_atomic


# -- kill -9 while the CLI writes ---------------------------------------------------------------
@pytest.mark.slow  # seconds of waiting or a second full run: `make test-slow`
def test_issue12_kill_9_leaves_the_old_or_the_new_file(tmp_path):
    """A few seeded kills of ``posturemap transition`` at random times (bench/crash_test.py: many)."""
    sys.path.insert(0, str(REPO / "bench"))
    try:
        import crash_test
    finally:
        sys.path.pop(0)
    result = crash_test.run(tmp_path, kills=4, seed=0)
    assert result["partial"] == 0, result
    assert result["old"] + result["new"] == result["kills"] == 4
    assert result["error_temps"] == 0


def test_read_regular_refuses_growth_beyond_the_cap(tmp_path):
    p = tmp_path / "f"
    p.write_bytes(b"x" * 100)
    assert fileio.read_regular(p, 100) == b"x" * 100
    with pytest.raises(fileio.UserError, match="too large"):
        fileio.read_regular(p, 99)


def test_written_bvh_reads_back(tmp_path):
    m = sample.clips()["run"]
    bvh.write(tmp_path / "r.bvh", m)
    back = bvh.read(tmp_path / "r.bvh")
    assert np.allclose(back.positions, m.positions, atol=1e-5)


def test_a_symbolic_link_is_written_through_and_kept(tmp_path):
    # An output named by a link (a project's "latest.bvh" pointing into a folder of takes): the
    # file it points to gets the data, the link stays a link; a dangling link makes its file.
    takes = tmp_path / "takes"
    takes.mkdir()
    real = takes / "take1.bvh"
    real.write_bytes(b"old")
    link = tmp_path / "latest.bvh"
    link.symlink_to(real)
    chain = tmp_path / "current.bvh"
    chain.symlink_to(link)
    fileio.write_bytes_atomic(chain, b"new")
    assert chain.is_symlink() and link.is_symlink() and real.read_bytes() == b"new"
    assert not [p for p in takes.iterdir() if p.name.startswith(fileio.TEMP_PREFIX)]
    dangling = tmp_path / "next.bvh"
    dangling.symlink_to(takes / "take2.bvh")
    fileio.write_bytes_atomic(dangling, b"made")
    assert dangling.is_symlink() and (takes / "take2.bvh").read_bytes() == b"made"
    # A loop of links is an error (OSError, which the callers name), not a file put in its place.
    loop = tmp_path / "loop1.bvh"
    loop.symlink_to(tmp_path / "loop2.bvh")
    (tmp_path / "loop2.bvh").symlink_to(loop)
    with pytest.raises(OSError):
        fileio.write_bytes_atomic(loop, b"x")
    assert loop.is_symlink() and (tmp_path / "loop2.bvh").is_symlink()
