"""Seeded CLI fuzzing with mutated BVH and map files (issue 12); the long mode is bench/fuzz_cli.py.

Each case must keep the error contract: exit 2 with one line ``posturemap: error: <file>...``
and no traceback or output file, or exit 0 with a finite output. Time and memory per case are
measured by the long mode, not asserted here.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "bench"))
import fuzz_cli  # noqa: E402

sys.path.pop(0)


@pytest.mark.parametrize("kind, cases", [("bvh", 200), ("map", 150),
                                         pytest.param("bvh", 600, marks=pytest.mark.slow),
                                         pytest.param("map", 400, marks=pytest.mark.slow)])
def test_issue12_cli_fuzz_has_no_escapes(tmp_path, kind, cases):
    result = fuzz_cli.fuzz(kind, cases, seed=12, folder=tmp_path)
    assert result["escapes"] == 0, result["examples"]
    assert result["cases"] == cases
    # The mutations must mostly produce refused files, and some still valid ones.
    assert result["refused"] > cases // 2 and result["accepted"] > 0, result


def test_mutated_map_that_decodes_to_nan_is_refused_by_validation(tmp_path):
    # Found by the fuzzer: 1e308 in an inactive dimension of space_fill passed the checks and
    # the transition decoded NaN rotations (the BVH writer then refused to write them).
    import numpy as np

    from posturemap.io.mapfile import MapFileError
    from posturemap.learn.model import PostureMap

    raw = fuzz_cli.good_map(tmp_path)
    m = fuzz_cli._members(raw)
    fill = fuzz_cli._load_npy(m["space_fill.npy"]).copy()
    active = fuzz_cli._load_npy(m["space_active.npy"])
    fill[np.flatnonzero(~active[:-1])[0]] = 1e308
    m["space_fill.npy"] = fuzz_cli._npy(fill)
    path = tmp_path / "fill.npz"
    path.write_bytes(fuzz_cli._zip(m))
    with pytest.raises(MapFileError, match="space_fill"):
        PostureMap.load(path)
