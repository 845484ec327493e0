"""``posturemap demo``: the whole pipeline on the bundled procedural sample or on real BVH files.

1. clips: the bundled sample (written as BVH and read back) or every BVH file of ``--data``;
2. learn a posture map from them and save it;
3. make transitions between clip pairs with the default method and write each as BVH and as
   glTF binary (``.glb``), with a filmstrip picture (``.png``) when matplotlib is installed
   (``pip install 'posturemap[preview]'``; without it the demo says so and goes on);
4. print the commands to try next (the studio on these clips and this map, one transition).

The sample run writes into ``out``; a ``--data NAME`` run into ``out-NAME`` (:func:`default_out`),
so the two never overwrite each other.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shlex
import time

from .io import bvh, gltf
from .core import kernels
from . import sample
from .learn.model import PostureMap
from .core.motion import length_unit, summary
from .synth.engine import transition
from .synth.request import DEFAULT_METHOD

SAMPLE_PAIRS = [("walk", "wave"), ("wave", "run"), ("run", "walk")]
DATA_PAIRS = [("walk", "run"), ("bow", "dance"), ("run", "walk-back")]
LENGTH = 20  # in-between frames of each transition (the default of transition())


def _pick(names: list[str], word: str) -> str | None:
    """The first clip whose name contains ``_word_`` (or ``word``), else None."""
    for token in (f"_{word}_", word):
        for n in names:
            if token in os.path.basename(n):
                return n
    return None


def default_out(data: str | None) -> str:
    """The demo's output folder: ``out`` for the sample, ``out-NAME`` for ``--data .../NAME``."""
    if data is None:
        return "out"
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", os.path.basename(os.path.normpath(os.path.abspath(data))))
    return f"out-{os.path.splitext(name)[0] or 'data'}"


def run(out: str, data: str | None = None, log=print) -> dict:
    """Run the pipeline, writing into folder ``out``; returns the paths written by role."""
    if data is not None and not os.path.exists(data):
        raise FileNotFoundError(2, "no such file or folder", data)
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
    pictures = importlib.util.find_spec("matplotlib") is not None
    short = lambda p: os.path.splitext(os.path.basename(p))[0].replace("dataset-1_", "")  # noqa: E731
    for i, (a, b) in enumerate(pairs):
        t0 = time.perf_counter()
        report = {}
        result = transition(clips[a], clips[b], model, method=DEFAULT_METHOD, report=report)
        used = report.get("method", DEFAULT_METHOD)  # what auto chose
        ms = (time.perf_counter() - t0) * 1e3
        note = " (the first call also compiles or loads the kernels)" if i == 0 else ""
        stem = os.path.join(out, f"{short(a)}_to_{short(b)}")
        n_a = len(clips[a])
        bvh.write(stem + ".bvh", result)
        gltf.write(stem + ".glb", result, parts=gltf.transition_parts(n_a, LENGTH, len(result)), split=True,
                   name=f"{short(a)}_to_{short(b)}", up=model.space_.up)
        written[f"{short(a)}->{short(b)}"] = stem + ".bvh"
        written[f"{short(a)}->{short(b)} glb"] = stem + ".glb"
        log(f"out   {stem}.bvh, .glb: {len(result)} frames ({n_a} of A + {LENGTH} {used} frames "
            f"+ {len(clips[b])} of B) in {ms:.1f} ms{note}")
        if pictures:
            from .io import preview

            preview.transition_filmstrip(result, n_a, LENGTH, stem + ".png", up=model.space_.up,
                                         title=f"{short(a)} -> {short(b)}: {LENGTH} {used} frames",
                                         unit=length_unit(result))
            written[f"{short(a)}->{short(b)} png"] = stem + ".png"
            log(f"      {stem}.png: filmstrip (A's last second grey, the transition orange, B blue)")
    if not pictures:
        log("note: no filmstrip pictures (matplotlib is missing: pip install 'posturemap[preview]')")
    inputs = " ".join(shlex.quote(p) for p in ([written[n] for n in sample.clips()] if data is None else [data]))
    a, b = pairs[0]
    log(f"done: open the .bvh or .glb files in {out}/ with Blender, three.js or a game engine. Next, try:")
    log(f"  posturemap serve {inputs} --map {shlex.quote(map_path)}    # the studio, on these clips")
    log(f"  posturemap transition {shlex.quote(a if data else written[a])} {shlex.quote(b if data else written[b])} "
        f"--map {shlex.quote(map_path)} --alpha 0.3 -o my_transition.glb --preview my_transition.png")
    return written
