"""``posturemap demo``: the whole pipeline on the bundled procedural sample or on real BVH files.

1. clips: the bundled sample (written as BVH and read back) or every BVH file of ``--data``;
2. learn a posture map from them and save it;
3. make transitions between clip pairs with the default method and write them as BVH.
"""

from __future__ import annotations

import os
import time

from . import bvh, kernels, sample
from .model import PostureMap
from .motion import summary
from .transition import DEFAULT_METHOD, transition

SAMPLE_PAIRS = [("walk", "wave"), ("wave", "run"), ("run", "walk")]
DATA_PAIRS = [("walk", "run"), ("bow", "dance"), ("run", "walk-back")]


def _pick(names: list[str], word: str) -> str | None:
    """The first clip whose name contains ``_word_`` (or ``word``), else None."""
    for token in (f"_{word}_", word):
        for n in names:
            if token in os.path.basename(n):
                return n
    return None


def run(out: str, data: str | None = None, log=print) -> dict:
    """Run the pipeline, writing into folder ``out``; returns the paths written by role."""
    os.makedirs(out, exist_ok=True)
    kernels.compiled()  # the demo trains a map
    written: dict[str, str] = {}
    if data is None:
        clips = {}
        for name, clip in sample.clips().items():
            path = os.path.join(out, f"sample_{name}.bvh")
            bvh.write(path, clip)
            clips[name] = bvh.read(path)
            written[name] = path
            log(f"clip  {path}: {summary(clips[name])}")
        pairs = SAMPLE_PAIRS
    else:
        loaded = bvh.read_inputs([data])
        clips = {p: m for p, m in loaded}
        log(f"clips {data}: {len(clips)} BVH files, {sum(len(m) for m in clips.values())} frames")
        names = list(clips)
        pairs = []
        for a, b in DATA_PAIRS:
            pa, pb = _pick(names, a), _pick(names, b)
            if pa and pb and pa != pb:
                pairs.append((pa, pb))
        if not pairs:
            pairs = [(names[0], names[min(1, len(names) - 1)])]
    t0 = time.perf_counter()
    model = PostureMap().fit(list(clips.values()), list(clips))
    map_path = os.path.join(out, "map.npz")
    model.save(map_path)
    written["map"] = map_path
    q = model.info_["quality"]
    log(f"map   {map_path}: learned in {time.perf_counter() - t0:.1f} s; neurons "
        + ", ".join(f"{c} {v['neurons']}" for c, v in q.items())
        + f"; invalid neurons {max(v['invalid_neurons'] for v in q.values()):.0%}")
    for i, (a, b) in enumerate(pairs):
        t0 = time.perf_counter()
        result = transition(clips[a], clips[b], model, method=DEFAULT_METHOD)
        ms = (time.perf_counter() - t0) * 1e3
        note = " (the first call also compiles or loads the kernels)" if i == 0 else ""
        short = lambda p: os.path.splitext(os.path.basename(p))[0].replace("dataset-1_", "")  # noqa: E731
        path = os.path.join(out, f"{short(a)}_to_{short(b)}.bvh")
        bvh.write(path, result)
        written[f"{short(a)}->{short(b)}"] = path
        log(f"out   {path}: {len(result)} frames ({len(clips[a])} of A + 20 {DEFAULT_METHOD} frames "
            f"+ {len(clips[b])} of B) in {ms:.1f} ms{note}")
    log(f"done: open the .bvh files in {out}/ with Blender or any BVH viewer, or run `posturemap serve`")
    return written
