"""Seeded fuzzing of the BVH reader.

Valid files (the procedural sample clips, always; a few real Bandai clips and CMU when
../shared/data is present) cut to a few dozen frames, then mutated thousands of times: byte
flips, deletions and insertions, random tokens (braces, keywords, NaN, huge numbers), line
duplication, deletion and swaps, truncation, swapped tokens. ``bvh.loads`` must either return
a valid Motion or raise BVHError naming the input; anything else fails. On a sample of the
inputs the fast (numba) and general (numpy) parsers must also agree.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from posturemap.core import quat
from posturemap.io import bvh
from posturemap.io.bvh import BVHError
from posturemap.core.motion import Motion

MAX_FRAMES = 40
FUZZ_COUNT = 700  # mutations per source in the quick runs; the slow ones make 1500-2500

TOKENS = [
    "{", "}", "{ }", "}}", "NaN", "nan", "-nan", "inf", "-inf", "Infinity", "1e999", "-1e999", "1e308",
    "1e-400", "0", "-0", "+0", "1.", ".5", "-.", ".", "-", "+", "e", "1e", "1e+", "5e-324", "0x1F", "1_000",
    "1,5", "--1", "99999999999999999999999", "0.000000000000000000000000001", "180", "-180", "360",
    "ROOT", "ROOT r", "JOINT", "JOINT j", "End Site", "End", "OFFSET", "OFFSET 1 2 3", "OFFSET 1 2",
    "CHANNELS", "CHANNELS 3 Xrotation Yrotation Zrotation", "CHANNELS 2 Xposition",
    "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation", "CHANNELS 1 Wrotation",
    "HIERARCHY", "MOTION", "Frames:", "Frames: 0", "Frames: -1", "Frames: 1e12", "Frames: inf",
    "Frame Time:", "Frame Time: 0", "Frame Time: -1", "Frame Time: 1e-320", "\x00", "\t", "\r", "\n",
    "\r\n", "\x0b", "\x0c", "\x1c", "\x85", "\u2028", "\ufeff", "\u00e9", "\u0661\u0662", "\xa0",
]
TOKENS_BYTES = [t.encode("utf-8") for t in TOKENS] + [b"\xff", b"\xfe\xff", b"\xc3", b"\x80\x80"]


def _cut(text: str, frames: int = MAX_FRAMES) -> str:
    """The file with at most ``frames`` frame lines (and a matching 'Frames:' line)."""
    lines = text.splitlines()
    ft = next(k for k, line in enumerate(lines) if line.strip().lower().startswith("frame time"))
    body = [line for line in lines[ft + 1:] if line.strip()][:frames]
    head = [re.sub(r"(?i)^(\s*frames:?\s*)\d+", rf"\g<1>{len(body)}", line) for line in lines[:ft + 1]]
    return "\n".join(head + body) + "\n"


def _header_lines(lines: list[bytes]) -> int:
    for k, line in enumerate(lines):
        if line.strip().lower().startswith(b"frame time"):
            return k + 1
    return len(lines)


def mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One to three random mutations of ``data``."""
    for _ in range(int(rng.integers(1, 4))):
        kind = int(rng.integers(0, 10))
        n = len(data)
        if n == 0:
            return bytes(rng.choice(TOKENS_BYTES))
        pos = int(rng.integers(0, n))
        if kind == 0:  # flip bits of one byte
            data = data[:pos] + bytes([data[pos] ^ int(rng.integers(1, 256))]) + data[pos + 1:]
        elif kind == 1:  # delete a short run of bytes
            data = data[:pos] + data[pos + int(rng.integers(1, 8)):]
        elif kind == 2:  # insert a token at a random byte
            data = data[:pos] + TOKENS_BYTES[int(rng.integers(len(TOKENS_BYTES)))] + data[pos:]
        elif kind == 3:  # truncate
            data = data[:pos]
        else:  # line-level: often in the hierarchy, where the structure is
            lines = data.split(b"\n")
            head = _header_lines(lines)
            if rng.uniform() < 0.6 and head > 1:
                k = int(rng.integers(0, head))
            else:
                k = int(rng.integers(0, len(lines)))
            if kind == 4:  # duplicate a line
                lines.insert(k, lines[k])
            elif kind == 5:  # delete a line
                del lines[k]
            elif kind == 6:  # swap two lines
                j = int(rng.integers(0, len(lines)))
                lines[k], lines[j] = lines[j], lines[k]
            elif kind == 7:  # replace one token of a line
                words = lines[k].split(b" ")
                words[int(rng.integers(len(words)))] = TOKENS_BYTES[int(rng.integers(len(TOKENS_BYTES)))]
                lines[k] = b" ".join(words)
            elif kind == 8:  # swap two tokens of a line
                words = lines[k].split()
                if len(words) > 1:
                    a, b = rng.choice(len(words), 2, replace=False)
                    words[a], words[b] = words[b], words[a]
                    lines[k] = b" ".join(words)
            else:  # insert a token as a line of its own
                lines.insert(k, TOKENS_BYTES[int(rng.integers(len(TOKENS_BYTES)))])
            data = b"\n".join(lines)
    return data


def _outcome(data, label):
    try:
        return bvh.loads(data, label)
    except BVHError as e:
        return e


def _as_text(data: bytes) -> str:
    """The text the reader sees in ``data`` (UTF-8 without BOM, else Latin-1)."""
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def _assert_same_outcome(a, b, data, label):
    if isinstance(a, BVHError) or isinstance(b, BVHError):
        assert type(a) is type(b) and str(a) == str(b), (label, a, b)
    else:
        assert a.skeleton.same_as(b.skeleton), label
        assert a.fps == b.fps and a.skeleton.euler_style == b.skeleton.euler_style, label
        assert np.array_equal(a.positions, b.positions), label
        # Angles beyond 1e6 degrees: numpy's sin(radians(x)) has lost the angle while the
        # kernel reduces it exactly; both are valid rotations.
        assert np.allclose(a.rotations, b.rotations, atol=1e-12) or _huge_number(data), label


def _huge_number(data: bytes | str) -> bool:
    if isinstance(data, str):
        data = data.encode("latin-1")
    numbers = re.findall(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", data)
    return any(abs(float(t)) > 1e6 for t in numbers)


def check_motion(m: Motion):
    """A Motion the reader returns must be internally consistent and finite."""
    assert isinstance(m, Motion)
    sk = m.skeleton
    num_joints = sk.num_joints
    assert num_joints >= 1 and m.num_frames >= 1
    assert m.rotations.shape == (m.num_frames, num_joints, 4)
    assert m.positions.shape == (m.num_frames, num_joints, 3)
    assert np.all(np.isfinite(m.rotations)) and np.all(np.isfinite(m.positions))
    assert np.allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-9)
    assert np.isfinite(m.fps) and m.fps > 0
    assert len(sk.channels) == num_joints and len(sk.names) == num_joints
    assert np.all(sk.parents < np.arange(num_joints))
    assert np.all(np.isfinite(sk.offsets))
    for j, offset in sk.end_sites:
        assert 0 <= j < num_joints and np.all(np.isfinite(offset))
    if np.abs(m.positions).max() < 1e100:
        assert np.all(np.isfinite(m.global_positions()))


# Every message the reader may give, as a regex of BVHError.what, with what must hold of the
# line it names (``line`` is that line's text, ``m`` the match); None: only the message is checked.
def _tokens(line):
    return line.split()


def _nonfinite(token):
    try:
        return not np.isfinite(float(token))
    except ValueError:
        return False


def _huge(token):
    try:
        return abs(float(token)) > bvh.MAX_ABS_VALUE
    except ValueError:
        return False


ERRORS = {
    r"binary data, not a BVH text file": None,
    r"empty file": None,
    r"no HIERARCHY section \(not a BVH file\?\)": None,
    r"missing MOTION section( \(unbalanced braces\))?": None,
    r"expected '\{', found (.+)": lambda line, m: repr(_tokens(line)[0][:40]) == m[1],
    r"MOTION before the hierarchy's braces are closed": lambda line, m: _tokens(line)[0].upper() == "MOTION",
    r"no joints before MOTION": lambda line, m: _tokens(line)[0].upper() == "MOTION",
    r"expected HIERARCHY, found (.+)": lambda line, m: repr(_tokens(line)[0][:40]) == m[1],
    r"ROOT inside another joint": lambda line, m: _tokens(line)[0].upper() == "ROOT",
    r"JOINT outside any ROOT": lambda line, m: _tokens(line)[0].upper() == "JOINT",
    r"JOINT inside an End Site": lambda line, m: _tokens(line)[0].upper() == "JOINT",
    r"(ROOT|JOINT) without a name": lambda line, m: len(_tokens(line)) == 1,
    r"joint name (.+) is used twice \(also on line (\d+)\)": lambda line, m: (
        _tokens(line)[0].upper() in ("ROOT", "JOINT") and repr(" ".join(_tokens(line)[1:])[:40]) == m[1]),
    r"End Site in the wrong place": lambda line, m: _tokens(line)[0].upper() == "END",
    r"'\{' without a joint": lambda line, m: _tokens(line)[0] == "{",
    r"unexpected text after '\{'": lambda line, m: _tokens(line)[0] == "{" and len(_tokens(line)) > 1,
    r"unbalanced '\}'": lambda line, m: _tokens(line)[0] == "}",
    r"End Site without OFFSET": lambda line, m: _tokens(line)[0] == "}",
    r"joint (.+) lacks OFFSET or CHANNELS": lambda line, m: _tokens(line)[0] == "}",
    r"OFFSET outside a joint": lambda line, m: _tokens(line)[0].upper() == "OFFSET",
    r"CHANNELS outside a joint": lambda line, m: _tokens(line)[0].upper() == "CHANNELS",
    r"unexpected (.+) in HIERARCHY": lambda line, m: repr(_tokens(line)[0][:40]) == m[1],
    r"OFFSET needs 3 numbers, found (\d+)": lambda line, m: len(_tokens(line)) - 1 == int(m[1]),
    r"OFFSET has a non-numeric value": lambda line, m: _tokens(line)[0].upper() == "OFFSET",
    r"OFFSET has a NaN or infinite value": lambda line, m: any(_nonfinite(t) for t in _tokens(line)[1:]),
    r"OFFSET has a value beyond \+-1e\+09": lambda line, m: any(_huge(t) for t in _tokens(line)[1:]),
    r"CHANNELS needs a count": lambda line, m: _tokens(line)[0].upper() == "CHANNELS",
    r"CHANNELS says (-?\d+) but lists (\d+)": lambda line, m: (int(m[1]) == int(_tokens(line)[1])
                                                            and len(_tokens(line)) - 2 == int(m[2])),
    r"unknown channel (.+)": lambda line, m: any(repr(t[:40]) == m[1] for t in _tokens(line)[2:]),
    r"a channel is listed twice": lambda line, m: len({t.lower() for t in _tokens(line)[2:]}) < len(_tokens(line)) - 2,
    r"(\d) rotation channels; need 0 or 3": lambda line, m: int(m[1]) != 3,
    r"expected '(Frames:|Frame Time:)', found (.+)": lambda line, m: repr(" ".join(line.split())[:40]) == m[2],
    r"MOTION without a frame count": lambda line, m: _tokens(line)[0].upper() == "MOTION",
    r"frame count (.+) is not a number": lambda line, m: "FRAMES" in line.upper(),
    r"frame count (.+) is not a whole number": lambda line, m: "FRAMES" in line.upper(),
    r"absurd frame count (-?\d+)": lambda line, m: "FRAMES" in line.upper(),
    r"missing 'Frame Time:'": None,
    r"frame time (.+) is not a number": lambda line, m: "FRAME" in line.upper(),
    r"frame time must be a positive number, got (.+)": lambda line, m: "FRAME" in line.upper(),
    r"frame time (.+) is out of range \(must be a positive number from .*\)": lambda line, m: "FRAME" in line.upper(),
    r"truncated: (\d+) frame lines but 'Frames: (\d+)'": lambda line, m: int(m[1]) < int(m[2]),
    r"(\d+) frame lines beyond 'Frames: (\d+)'": lambda line, m: int(m[1]) >= 1 and line.strip() != "",
    r"frame has (\d+) values, expected (\d+)": lambda line, m: (len(_tokens(line)) == int(m[1])
                                                               and int(m[1]) != int(m[2])),
    r"NaN or infinite value in frame data": lambda line, m: any(_nonfinite(t) for t in _tokens(line)),
    r"value beyond \+-1e\+09 in frame data": lambda line, m: any(_huge(t) for t in _tokens(line)),
    r"non-numeric value (.+)": lambda line, m: any(repr(t[:40]) == m[1] for t in _tokens(line)),
}
ERROR_PATTERNS = [(re.compile(k), v) for k, v in ERRORS.items()]
_LINE_BREAK = re.compile("\r\n|[\n\r\x0b\x0c\x1c\x1d\x1e\x85\u2028\u2029]")  # as str.splitlines()


def error_kind(e: BVHError, data, label: str) -> str:
    """The ERRORS pattern ``e`` matches, after checking the line it names; fails otherwise."""
    assert str(e).startswith(label) and "\n" not in str(e), str(e)
    assert e.path == label
    text = data if isinstance(data, str) else _as_text(data)
    lines = _LINE_BREAK.split(text)
    for pattern, check in ERROR_PATTERNS:
        m = pattern.fullmatch(e.what)
        if m:
            break
    else:
        pytest.fail(f"unknown message {e.what!r} for {label}")
    if e.line is not None:
        assert 1 <= e.line <= len(lines), (str(e), len(lines))
        if check is not None:
            line = lines[e.line - 1]
            assert line.strip() and check(line, m), f"{e}: but line {e.line} is {line[:120]!r}"
    return pattern.pattern


def fuzz(sources: dict[str, bytes], count: int, seed: int, tmp_path, monkeypatch, compare_every: int = 3):
    """Mutate each source ``count`` times; returns ``(accepted, {error pattern: count}, escapes)``.

    Every rejection must be a BVHError with a known message whose line says what the message
    claims; ``escapes`` lists the inputs (saved under ``tmp_path``) on which anything else
    escaped ``bvh.loads``.
    """
    rng = np.random.default_rng(seed)
    kernels = bvh._fast_kernels()
    assert kernels is not None  # the fast parser is the one under test; the general one checks it
    accepted = 0
    kinds: dict[str, int] = {}
    escapes = []
    for name, original in sources.items():
        for k in range(count):
            data = mutate(original, rng)
            if k % 2:  # text input too (the reader takes bytes or str)
                data = data.decode("latin-1")
            label = f"fuzz-{name}-{k}.bvh"
            try:
                result = bvh.loads(data, label)
            except BVHError as e:
                kind = error_kind(e, data, label)
                kinds[kind] = kinds.get(kind, 0) + 1
                result = e
            except Exception as e:  # noqa: BLE001 - that is the point of the test
                saved = tmp_path / label
                saved.write_bytes(data if isinstance(data, bytes) else data.encode("latin-1"))
                escapes.append(f"{type(e).__name__} on {saved}: {e}")
                continue
            else:
                check_motion(result)
                accepted += 1
                if k % 5 == 0:  # what was accepted can be written and read back
                    back = bvh.loads(bvh.dumps(result), "round-trip")
                    assert back.skeleton.same_as(result.skeleton)
                    assert back.num_frames == result.num_frames
                    np.testing.assert_allclose(back.positions, result.positions, rtol=1e-6, atol=1e-6)
                    err = quat.angle_between(back.rotations, result.rotations).max()
                    # 1e-4 rad: near gimbal lock the written Euler angles lose a few digits
                    assert err < 1e-4 or _huge_number(data), (label, err)
            if k % compare_every == 0:  # the general parser agrees with the fast one
                monkeypatch.setattr(bvh, "_fast_kernels", lambda: None)
                try:
                    other = _outcome(data, label)
                finally:
                    monkeypatch.setattr(bvh, "_fast_kernels", lambda: kernels)
                _assert_same_outcome(result, other, data, label)
            elif isinstance(data, bytes):  # bytes (header-only decoding) and str agree
                _assert_same_outcome(result, _outcome(_as_text(data), label), data, label)
    return accepted, kinds, escapes


# Messages each seeded run must produce (the mutations reach them; a reader that stops
# checking one of these would let the inputs through or fail differently).
FRAME_ERRORS = {
    r"truncated: (\d+) frame lines but 'Frames: (\d+)'", r"(\d+) frame lines beyond 'Frames: (\d+)'",
    r"frame has (\d+) values, expected (\d+)", r"NaN or infinite value in frame data", r"non-numeric value (.+)",
}
HIERARCHY_ERRORS = {
    r"expected '\{', found (.+)", r"unbalanced '\}'", r"unknown channel (.+)", r"CHANNELS says (-?\d+) but lists (\d+)",
    r"OFFSET needs 3 numbers, found (\d+)", r"missing MOTION section( \(unbalanced braces\))?",
    r"unexpected (.+) in HIERARCHY", r"expected '(Frames:|Frame Time:)', found (.+)",
}


def check_run(accepted, kinds, escapes, total, min_accepted, required):
    assert not escapes, f"{len(escapes)} exceptions other than BVHError escaped bvh.loads:\n" + "\n".join(escapes[:20])
    rejected = sum(kinds.values())
    assert accepted + rejected == total  # every input was either read or refused (no escape)
    assert accepted >= min_accepted and rejected >= total // 2, (accepted, rejected)
    missing = sorted(required - set(kinds))
    assert not missing, f"no mutation produced {missing}; got {sorted(kinds)}"


def test_fuzz_sample_clips(sample_clips, tmp_path, monkeypatch):
    sources = {name: _cut(bvh.dumps(clip)).encode() for name, clip in sample_clips.items()}
    sources["crlf"] = sources["walk"].replace(b"\n", b"\r\n")
    accepted, kinds, escapes = fuzz(sources, count=FUZZ_COUNT, seed=1234, tmp_path=tmp_path, monkeypatch=monkeypatch)
    check_run(accepted, kinds, escapes, 4 * FUZZ_COUNT, FUZZ_COUNT // 5, FRAME_ERRORS | HIERARCHY_ERRORS)


@pytest.mark.slow
def test_fuzz_sample_clips_long(sample_clips, tmp_path, monkeypatch):
    sources = {name: _cut(bvh.dumps(clip)).encode() for name, clip in sample_clips.items()}
    sources["crlf"] = sources["walk"].replace(b"\n", b"\r\n")
    accepted, kinds, escapes = fuzz(sources, count=2500, seed=4321, tmp_path=tmp_path, monkeypatch=monkeypatch)
    check_run(accepted, kinds, escapes, 10000, 500, FRAME_ERRORS | HIERARCHY_ERRORS)


def test_fuzz_real_files(bandai_files, cmu_file, tmp_path, monkeypatch):
    picks = [bandai_files[0], bandai_files[len(bandai_files) // 2], bandai_files[-1], cmu_file]
    sources = {p.stem: _cut(p.read_text()).encode() for p in picks}
    accepted, kinds, escapes = fuzz(sources, count=250, seed=99, tmp_path=tmp_path, monkeypatch=monkeypatch)
    check_run(accepted, kinds, escapes, 1000, 50, FRAME_ERRORS | HIERARCHY_ERRORS)


@pytest.mark.slow
def test_fuzz_real_files_long(bandai_files, cmu_file, tmp_path, monkeypatch):
    picks = [bandai_files[1], bandai_files[len(bandai_files) // 3], bandai_files[-2], cmu_file]
    sources = {p.stem: _cut(p.read_text()).encode() for p in picks}
    accepted, kinds, escapes = fuzz(sources, count=1500, seed=999, tmp_path=tmp_path, monkeypatch=monkeypatch)
    check_run(accepted, kinds, escapes, 6000, 300, FRAME_ERRORS | HIERARCHY_ERRORS)


def test_fuzz_large_inputs(sample_clips, tmp_path, monkeypatch):
    # Above 64 KiB the reader decodes only the header; mutate headers and bodies of such files.
    walk = sample_clips["walk"]
    long_walk = Motion(walk.skeleton, np.tile(walk.rotations, (4, 1, 1)), np.tile(walk.positions, (4, 1, 1)),
                       walk.fps)
    big = bvh.dumps(long_walk).encode()
    assert len(big) > 65536
    sources = {"big": big, "big-crlf": big.replace(b"\n", b"\r\n")}
    accepted, kinds, escapes = fuzz(sources, count=150, seed=7, tmp_path=tmp_path, monkeypatch=monkeypatch)
    check_run(accepted, kinds, escapes, 300, 10, {r"truncated: (\d+) frame lines but 'Frames: (\d+)'",
                                                        r"frame has (\d+) values, expected (\d+)", r"non-numeric value (.+)"})


def test_fuzz_reports_what_escapes_and_unknown_messages(sample_clips, tmp_path, monkeypatch):
    # The harness itself: an exception other than BVHError is collected (not swallowed), and a
    # BVHError whose message or line is not one of ERRORS fails the test.
    source = {"walk": _cut(bvh.dumps(sample_clips["walk"])).encode()}
    real = bvh._parse_frames

    def broken(raw, text, offset, last_lineno, num_frames, skeleton, path):
        if num_frames % 3 == 1:
            raise IndexError("a bug")
        return real(raw, text, offset, last_lineno, num_frames, skeleton, path)

    monkeypatch.setattr(bvh, "_parse_frames", broken)
    _, _, escapes = fuzz(source, count=60, seed=5, tmp_path=tmp_path, monkeypatch=monkeypatch, compare_every=10**9)
    assert escapes and all(e.startswith("IndexError on ") for e in escapes)
    monkeypatch.setattr(bvh, "_parse_frames", real)
    with pytest.raises(pytest.fail.Exception, match="unknown message"):
        error_kind(BVHError("x.bvh", 3, "something new"), "a\nb\nc\n", "x.bvh")
    with pytest.raises(AssertionError, match="but line 2 is"):  # the line does not hold what is claimed
        error_kind(BVHError("x.bvh", 2, "frame has 2 values, expected 3"), "1 2\n1 2 3 4\n", "x.bvh")
    with pytest.raises(AssertionError):  # a line beyond the file
        error_kind(BVHError("x.bvh", 9, "NaN or infinite value in frame data"), "1 2\n", "x.bvh")


def test_fuzz_sources_are_valid(sample_clips):
    for clip in sample_clips.values():
        m = bvh.loads(_cut(bvh.dumps(clip)))
        check_motion(m)
        assert m.num_frames == min(MAX_FRAMES, clip.num_frames)


def test_mutate_is_deterministic():
    data = b"HIERARCHY\nROOT a\n{\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n0\n"
    a = [mutate(data, np.random.default_rng(5)) for _ in range(3)]
    assert a[0] == a[1] == a[2]
    assert mutate(data, np.random.default_rng(6)) != a[0] or mutate(data, np.random.default_rng(7)) != a[0]
