"""``posturemap demo``: the whole pipeline on the bundled procedural sample or on real BVH files."""

from __future__ import annotations

import os

from . import bvh, sample
from .motion import summary


def run(out: str, data: str | None = None, log=print) -> dict:
    """Write the sample clips, read them back and report; returns the paths written."""
    os.makedirs(out, exist_ok=True)
    written = {}
    for name, clip in sample.clips().items():
        path = os.path.join(out, f"sample_{name}.bvh")
        bvh.write(path, clip)
        back = bvh.read(path)
        log(f"{path}: {summary(back)}")
        written[name] = path
    return written
