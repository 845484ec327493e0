"""Seeded fuzzing of the command line with mutated BVH and map files (issue 12).

Each case writes one mutated file and runs ``posturemap`` on it in-process (``cli.main``):

- ``bvh``: real BVH files (the procedural sample, Bandai and CMU clips when
  ``$POSTUREMAP_DATA`` is there; cut to 40 frames) mutated by ``tests/test_fuzz_bvh.mutate``
  (bit flips, truncation, token and line edits, NaN, huge numbers, braces) plus header edits
  (frame time and frame count set to hostile values); run as ``inspect FILE`` and, every
  fourth case, ``transition FILE GOOD -o OUT``;
- ``map``: a map file trained on the sample, mutated at the byte level (bit flips,
  truncation), in its JSON metadata (a random field set to a hostile value: huge or
  infinite numbers, NaN, deep nesting, wrong types) or in its arrays (NaN, zeros, another
  dtype or shape, an ``.npy`` header declaring a huge shape); run as ``inspect FILE`` and,
  every fourth case, ``transition A B --map FILE -o OUT``.

A case *escapes* when the command raises, exits with a code other than 0 or 2, prints a
traceback, prints anything but one line ``posturemap: error: <file>...: <what>`` with exit 2,
leaves an output file after exit 2 or writes a non-finite output with exit 0. The long mode
also measures each case's time and the worker's peak RSS:

    python bench/fuzz_cli.py --cases 10000 --seed 0

prints one JSON line per kind (cases, accepted, refused, escapes, slowest case, peak RSS).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

from posturemap.io import bvh
from posturemap import cli, sample
from posturemap.learn.model import PostureMap

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from test_fuzz_bvh import _cut, mutate  # noqa: E402 - the BVH mutations, shared with the reader's fuzz test

sys.path.pop(0)

HOSTILE = [None, True, -1, 0, 3, 2 ** 63, 10 ** 400, 1e308, "1e999", "NaN", "x", "", [], {}, [[[[[[[]]]]]]],
           {"a": {"b": {"c": [1]}}}, -1e-320, 0.5, "auto", [1, 2, 3], "Z" * 10000]
FRAME_HEADERS = [b"Frame Time: 100", b"Frame Time: 1e308", b"Frame Time: 0", b"Frame Time: -0.03",
                 b"Frame Time: nan", b"Frames: 999999999", b"Frames: 1e300", b"Frames: -5", b"Frames: 0",
                 b"Frame Time: 1e-9"]


# -- inputs ----------------------------------------------------------------------------------
def bvh_sources() -> dict[str, bytes]:
    """Valid BVH texts to mutate: the sample, and real clips when the data folder exists."""
    out = {f"sample_{n}": bvh.dumps(m).encode() for n, m in sample.clips().items()}
    data = Path(os.environ.get("POSTUREMAP_DATA") or Path(__file__).resolve().parents[2] / "shared" / "data")
    for p in sorted((data / "bandai1").glob("*.bvh"))[:3] + [data / "cmu" / "01_01.bvh"]:
        if p.is_file():
            out[p.stem] = _cut(p.read_text(encoding="utf-8", errors="replace")).encode()
    return out


def good_map(folder: Path) -> bytes:
    clips = sample.clips()
    path = folder / "good.npz"
    PostureMap(seed=0).fit(list(clips.values()), list(clips)).save(str(path))
    return path.read_bytes()


def mutate_bvh(data: bytes, rng: np.random.Generator) -> bytes:
    if rng.random() < 0.15:  # a hostile frame header
        lines = data.split(b"\n")
        key = b"Frame Time" if rng.random() < 0.5 else b"Frames"
        k = next((i for i, line in enumerate(lines) if line.startswith(key)), None)
        if k is not None:
            lines[k] = FRAME_HEADERS[int(rng.integers(len(FRAME_HEADERS)))]
        return b"\n".join(lines)
    return mutate(data, rng)


def _members(raw: bytes) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(raw)) as z:
        return {i.filename: z.read(i.filename) for i in z.infolist()}


def _zip(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for k, v in members.items():
            z.writestr(k, v)
    return buf.getvalue()


def _npy(a: np.ndarray) -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array(buf, a, allow_pickle=False)
    return buf.getvalue()


def _load_npy(raw: bytes) -> np.ndarray:
    return np.lib.format.read_array(io.BytesIO(raw), allow_pickle=False)


def _set_random_field(obj, rng, depth=0):
    """Set one random field somewhere in a JSON object to a hostile value."""
    keys = list(obj) if isinstance(obj, dict) else list(range(len(obj)))
    if not keys:
        return
    k = keys[int(rng.integers(len(keys)))]
    if isinstance(obj[k], (dict, list)) and obj[k] and rng.random() < 0.6 and depth < 4:
        _set_random_field(obj[k], rng, depth + 1)
    else:
        obj[k] = HOSTILE[int(rng.integers(len(HOSTILE)))]


def mutate_map(raw: bytes, rng: np.random.Generator) -> bytes:
    with np.errstate(all="ignore"):  # casts of NaN and huge values are the point
        return _mutate_map(raw, rng)


def _mutate_map(raw: bytes, rng: np.random.Generator) -> bytes:
    kind = int(rng.integers(0, 6))
    if kind == 0:  # bit flips anywhere
        b = bytearray(raw)
        for _ in range(int(rng.integers(1, 8))):
            b[int(rng.integers(len(b)))] ^= int(rng.integers(1, 256))
        return bytes(b)
    if kind == 1:  # truncation
        return raw[: int(rng.integers(0, len(raw)))]
    m = _members(raw)
    if kind in (2, 3):  # metadata: a hostile field, or raw text edits (numbers, nesting)
        meta = json.loads(_load_npy(m["meta.npy"]).tobytes())
        if kind == 2:
            _set_random_field(meta, rng)
            text = json.dumps(meta)
        else:
            text = json.dumps(meta)
            edits = ["1e999", "-1e999", "9" * 400, "NaN", "[" * 5000 + "]" * 5000, "\"", "{}", "null"]
            digits = [i for i, ch in enumerate(text) if ch.isdigit()]
            i = digits[int(rng.integers(len(digits)))]
            text = text[:i] + edits[int(rng.integers(len(edits)))] + text[i + 1:]
        m["meta.npy"] = _npy(np.frombuffer(text.encode(), dtype=np.uint8))
        return _zip(m)
    names = [k for k in m if k != "meta.npy"]
    name = names[int(rng.integers(len(names)))]
    a = _load_npy(m[name])
    if kind == 4:  # values and dtypes
        choice = int(rng.integers(0, 5))
        if choice == 0 and a.size:
            a = a.astype(np.float64)
            a.flat[int(rng.integers(a.size))] = [np.nan, np.inf, -np.inf, 1e308][int(rng.integers(4))]
        elif choice == 1:
            a = np.zeros_like(a)
        elif choice == 2:
            a = a.astype([np.int8, np.float16, np.complex64, np.uint64, bool][int(rng.integers(5))])
        elif choice == 3:
            a = a.reshape(-1) if a.ndim > 1 else a[: max(0, len(a) - 1)]
        else:
            a = np.concatenate([a, a]) if a.ndim else a
        m[name] = _npy(a)
    else:  # a header that lies about the shape
        shape = tuple(int(rng.choice([0, 1, 3, 2 ** 31, 2 ** 40, 10 ** 12])) for _ in range(int(rng.integers(1, 4))))
        head = io.BytesIO()
        np.lib.format.write_array_header_1_0(head, {"descr": a.dtype.str, "fortran_order": False, "shape": shape})
        m[name] = head.getvalue() + m[name][len(m[name]) - a.nbytes:]
    return _zip(m)


# -- running cases ---------------------------------------------------------------------------
def run_case(argv: list[str], inputs: tuple[str, ...], out: Path | None) -> tuple[int | None, str | None]:
    """Run ``posturemap argv``: its exit code, and None when the error contract holds, else what
    escaped. ``inputs`` are the files an error may name (the mutated one, or the clip it was
    compared with)."""
    if out is not None and out.exists():
        out.unlink()
    stdout, stderr = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
            code = cli.main(argv)
    except BaseException as e:  # noqa: BLE001 - what the fuzzer looks for
        return None, f"raised {type(e).__name__}: {str(e)[:200]}"
    err = stderr.getvalue()
    if "Traceback" in err:
        return code, "traceback"
    if code == 2:
        lines = err.splitlines()
        if len(lines) != 1 or not any(lines[0].startswith(f"posturemap: error: {p}") for p in inputs):
            return code, f"bad error output {err[:200]!r}"
        if out is not None and out.exists():
            return code, "output file left after an error"
        return code, None
    if code != 0:
        return code, f"exit code {code}"
    if out is not None:
        m = bvh.read(out)
        if not (np.all(np.isfinite(m.rotations)) and np.all(np.isfinite(m.positions))):
            return code, "non-finite output written"
    return code, None


def fuzz(kind: str, cases: int, seed: int, folder: Path, log=None) -> dict:
    """``cases`` seeded cases of ``kind`` ("bvh" or "map") in ``folder``; returns the counts."""
    folder = Path(folder)
    rng = np.random.default_rng(seed)
    clips = sample.clips()
    good_a, good_b = folder / "good_a.bvh", folder / "good_b.bvh"
    bvh.write(good_a, clips["walk"])
    bvh.write(good_b, clips["run"])
    if kind == "bvh":
        sources = bvh_sources()
        names = sorted(sources)
    else:
        original = good_map(folder)
    out = folder / "out.bvh"
    counts = {"kind": kind, "cases": 0, "accepted": 0, "refused": 0, "escapes": 0, "examples": [],
              "slowest_s": 0.0}
    base_rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    for i in range(cases):
        if kind == "bvh":
            data = mutate_bvh(sources[names[i % len(names)]], rng)
            path = folder / "case.bvh"
            argv = (["transition", str(path), str(good_b), "-o", str(out), "--method", "spline"] if i % 4 == 3
                    else ["inspect", str(path)])
        else:
            data = mutate_map(original, rng)
            path = folder / "case.npz"
            argv = (["transition", str(good_a), str(good_b), "--map", str(path), "-o", str(out), "--method", "upm"]
                    if i % 4 == 3 else ["inspect", str(path)])
        path.write_bytes(data)
        t0 = time.perf_counter()
        code, problem = run_case(argv, (str(path), str(good_a), str(good_b)),
                                 out if argv[0] == "transition" else None)
        counts["slowest_s"] = max(counts["slowest_s"], time.perf_counter() - t0)
        counts["cases"] += 1
        if problem:
            counts["escapes"] += 1
            if len(counts["examples"]) < 5:
                counts["examples"].append({"case": i, "problem": problem})
                (folder / f"escape_{kind}_{i}{path.suffix}").write_bytes(data)
            if log:
                log(f"case {i}: {problem}")
        else:
            counts["accepted" if code == 0 else "refused"] += 1
    counts["slowest_s"] = round(counts["slowest_s"], 3)
    counts["peak_rss_mb"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1)
    counts["rss_growth_mb"] = round((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - base_rss) / 1024, 1)
    return counts


def main():
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=10_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kind", choices=("bvh", "map", "both"), default="both")
    args = ap.parse_args()
    for kind in (("bvh", "map") if args.kind == "both" else (args.kind,)):
        with tempfile.TemporaryDirectory(prefix=f"posturemap-fuzz-{kind}-") as tmp:
            t0 = time.perf_counter()
            result = fuzz(kind, args.cases, args.seed, Path(tmp), log=lambda s: print(s, file=sys.stderr))
            result["seconds"] = round(time.perf_counter() - t0, 1)
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
