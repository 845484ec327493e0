"""Speed figures of the bench: transition latency, training against MiniSom, ``bench/`` scripts."""

from __future__ import annotations

import importlib.util
import inspect
import time
from pathlib import Path

import numpy as np

from ..learn.features import CLASSES
from .baselines import engine_call
from .protocol import CROSS_LENGTH, METHODS, Settings, _log, random_pairs
from .report import jsonable

def latency(state: dict, calls: int, seed: int) -> dict:
    """Median and p99 (microseconds) of single generate calls per method (cross-clip, L=20)."""
    engines, test = state["engines"], state["test"]
    pairs = random_pairs([len(m) for m in test], calls, seed + 2)
    out = {}
    for m in METHODS:
        if m == "zero-velocity":
            continue
        eng, meth, feet = engine_call(engines, m)
        for a, b, a_end, b_start in pairs[:20]:  # warm-up: compiled kernels, caches
            eng.generate(str(a), str(b), length=CROSS_LENGTH, a_end=a_end, b_start=b_start, method=meth, foot_lock=feet)
        times = np.empty(len(pairs))
        for i, (a, b, a_end, b_start) in enumerate(pairs):
            t0 = time.perf_counter_ns()
            eng.generate(str(a), str(b), length=CROSS_LENGTH, a_end=a_end, b_start=b_start, method=meth, foot_lock=feet)
            times[i] = time.perf_counter_ns() - t0
        out[m] = {"median_us": float(np.median(times)) / 1e3, "p99_us": float(np.percentile(times, 99)) / 1e3,
                  "calls": len(pairs), "neurons": [int(t.n_neurons) for t in eng.model.maps_]}
    return out


def training_speed(state: dict, seed: int) -> list[dict]:
    """Per class: UPM (one thread) against MiniSom on the same features and neuron count."""
    from ..learn.upm import UniformPostureMap

    model, parts = state["model"], state["model"].space_.split(state["x_train"])
    seq = np.concatenate([np.full(len(m), i) for i, m in enumerate(state["train"])])
    rows = []
    for c, info in enumerate(state["som_info"]):
        m = model.maps_[c]
        upm = UniformPostureMap(model.radius, model.neighborhood, model.learning_rate, model.epochs,
                                seed + c, m.period_)
        t0 = time.perf_counter()
        upm.fit(parts[c], seq)
        sec = time.perf_counter() - t0
        rows.append({"class": CLASSES[c], "samples": len(parts[c]), "dims": int(parts[c].shape[1]),
                     "upm_neurons": upm.n_neurons, "upm_epochs": int(model.epochs), "upm_seconds": sec,
                     "upm_samples_per_s": model.epochs * len(parts[c]) / sec,
                     "som_neurons": info["neurons"], "som_epochs": info["epochs"],
                     "som_seconds": info["seconds"], "som_samples_per_s": info["samples_per_s"]})
    return rows


def bench_dir() -> Path:
    """The repository's ``bench/`` folder (next to ``src/``)."""
    return Path(__file__).resolve().parents[3] / "bench"


def run_bench_script(name: str, data_dir: Path, settings: Settings, seed: int, log=_log) -> dict:
    """Import ``bench/<name>.py`` by path and call its ``run``; never raises.

    Arguments are passed by name when ``run`` takes them: ``data_dir``/``data``, ``repeat``
    (3), ``quick``, ``seed``. Returns ``{"status": "ok", "result": ..., "markdown": ...}`` or
    ``{"status": "absent"|"failed", "reason": ...}``.
    """
    path = bench_dir() / f"{name}.py"
    if not path.is_file():
        return {"status": "absent", "reason": f"{path} not found"}
    t0 = time.perf_counter()
    try:
        spec = importlib.util.spec_from_file_location(f"posturemap_bench_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        params = inspect.signature(mod.run).parameters
        offer = {"data_dir": data_dir, "data": data_dir, "repeat": 3, "quick": settings.quick, "seed": seed}
        kwargs = {k: v for k, v in offer.items() if k in params}
        result = mod.run(**kwargs)
        md = mod.markdown(result) if hasattr(mod, "markdown") else None
    except Exception as e:  # noqa: BLE001 - another team's script: report, do not crash
        log(f"bench/{name}.py failed: {type(e).__name__}: {e}")
        return {"status": "failed", "reason": f"{type(e).__name__}: {' '.join(str(e).split())[:300]}"}
    log(f"bench/{name}.py: {time.perf_counter() - t0:.1f} s")
    return {"status": "ok", "seconds": time.perf_counter() - t0, "result": jsonable(result), "markdown": md}
