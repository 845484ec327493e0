"""The command line's error contract, for tests: run ``posturemap`` in-process and check a refusal."""

from __future__ import annotations

import re

from posturemap import cli


def run(capsys, *argv) -> tuple[int, str, str]:
    """``posturemap ARGV`` in-process: (exit code, stdout, stderr)."""
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_refused(capsys, path, *argv, words=()):
    """``posturemap ARGV`` fails as the contract says (exit 2, one line
    ``posturemap: error: <path>: <what>``, or ``<path>:<line>: <what>`` for a file's line, no
    traceback), naming ``path``; returns the line."""
    code, out, err = run(capsys, *argv)
    assert code == 2, (code, out, err)
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert re.match(rf"posturemap: error: {re.escape(str(path))}(:\d+)?: ", lines[0]), lines[0]
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]
