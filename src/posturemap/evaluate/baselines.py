"""Stand-ins for the posture map: the classic SOM key (MiniSom) and fixed keys; which engine
serves which method of the bench."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from ..learn.features import CLASSES
from ..core.motion import Motion
from ..synth.engine import TransitionEngine
from .protocol import VARIANTS, method_spec

def som_grid(n: int) -> tuple[int, int]:
    """Rows and columns of a SOM grid with about ``n`` neurons, as square as possible.

    Exactly ``n`` when ``n`` has a divisor between sqrt(n)/2 and sqrt(n); otherwise
    ``round(sqrt n)`` rows and enough columns (at most one row's worth more than ``n``).
    """
    root = math.isqrt(n)
    for r in range(root, max(1, math.ceil(root / 2)) - 1, -1):
        if r > 0 and n % r == 0 and r >= root / 2:
            return r, n // r
    r = max(1, round(math.sqrt(n)))
    return r, math.ceil(n / r)


@dataclass
class KeyTable:
    """A stand-in for one class map: the attributes :class:`TransitionEngine` reads."""

    weights_: np.ndarray
    period_: np.ndarray
    edges_: np.ndarray

    @property
    def n_neurons(self) -> int:
        return len(self.weights_)

    def distances(self, X) -> np.ndarray:
        X = np.atleast_2d(np.asarray(X, dtype=float))
        return np.linalg.norm(X[:, None, :] - self.weights_[None], axis=-1)


@dataclass
class KeyModel:
    """A stand-in for :class:`PostureMap` with other key tables (same skeleton and features).

    Anything else the engine reads from a map (e.g. a motion library) comes from ``base``,
    the map it stands in for.
    """

    skeleton_: object
    space_: object
    maps_: list
    base: object = None

    def __getattr__(self, name):
        base = self.__dict__.get("base")
        if base is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(base, name)


def grid_edges(rows: int, cols: int) -> np.ndarray:
    """4-neighbour edges (E, 2) of a rows x cols grid, neurons numbered row by row."""
    idx = np.arange(rows * cols).reshape(rows, cols)
    e = [np.stack([idx[:, :-1].ravel(), idx[:, 1:].ravel()], 1), np.stack([idx[:-1].ravel(), idx[1:].ravel()], 1)]
    return np.concatenate(e).astype(np.int64)


def train_som(x: np.ndarray, n_neurons: int, epochs: int, seed: int):
    """A MiniSom with about ``n_neurons`` neurons trained on ``x (n, d)``; returns (som, rows, cols).

    Classic settings: Gaussian neighbourhood from sigma = max(rows, cols) / 4 decreasing
    linearly to 1, learning rate 0.5 decreasing linearly to 0, weights started at random
    samples, ``round(epochs * n)`` updates in seeded random order.
    """
    from minisom import MiniSom

    rows, cols = som_grid(n_neurons)
    som = MiniSom(rows, cols, x.shape[1], sigma=max(rows, cols) / 4.0, learning_rate=0.5,
                  decay_function="linear_decay_to_zero", sigma_decay_function="linear_decay_to_one",
                  neighborhood_function="gaussian", random_seed=seed)
    som.random_weights_init(x)
    som.train(x, max(1, round(epochs * len(x))), random_order=True)
    return som, rows, cols


def som_model(model, parts: list[np.ndarray], epochs: int, seed: int, log=print):
    """A :class:`KeyModel` whose class maps are classic SOMs trained on the same class features.

    Returns ``(model, info)`` with per-class neuron counts and training seconds.
    """
    maps, info = [], []
    for c, (m, x) in enumerate(zip(model.maps_, parts)):
        t0 = time.perf_counter()
        som, rows, cols = train_som(x, m.n_neurons, epochs, seed + c)
        seconds = time.perf_counter() - t0
        w = np.ascontiguousarray(som.get_weights().reshape(rows * cols, -1), dtype=np.float64)
        maps.append(KeyTable(w, np.full(w.shape[1], np.inf), grid_edges(rows, cols)))
        info.append({"class": CLASSES[c], "grid": [rows, cols], "neurons": rows * cols,
                     "upm_neurons": m.n_neurons, "samples": len(x), "epochs": epochs,
                     "seconds": seconds, "samples_per_s": epochs * len(x) / seconds})
        log(f"  som {CLASSES[c]}: {rows}x{cols} grid ({rows * cols} neurons, UPM {m.n_neurons}), "
            f"{seconds:.1f} s")
    return KeyModel(model.skeleton_, model.space_, maps, model), info


def fixed_key_model(model) -> KeyModel:
    """A :class:`KeyModel` with one neuron per class, set before each call (diagnostic keys)."""
    space = model.space_
    maps = [KeyTable(np.zeros((1, len(d))), np.full(len(d), np.inf), np.zeros((0, 2), np.int64))
            for d in space.class_dims]
    return KeyModel(model.skeleton_, space, maps, model)


def centred(motion: Motion, root: int, up: int) -> Motion:
    """``motion`` with the root's horizontal translation set to 0 in every frame.

    Postures exclude the horizontal position, so a map learned from it is the same; but
    :func:`posturemap.core.motion.up_axis` measures the spread of all joints, including a fixed
    top joint at the origin (Bandai's ``joint_Root``), and takes the walking direction for up
    once the character is far from the origin. Centring keeps it right.
    """
    pos = motion.positions.copy()
    pos[:, root, [a for a in range(3) if a != up]] = 0.0
    return Motion(motion.skeleton, motion.rotations, pos, motion.fps)


def set_key(key_model: KeyModel, x: np.ndarray):
    """Make ``x`` (full feature vector) the only neuron of every class of ``key_model``."""
    for m, d in zip(key_model.maps_, key_model.space_.class_dims):
        m.weights_ = np.ascontiguousarray(x[d][None], dtype=np.float64)


def engine_call(engines: dict, method: str) -> tuple[TransitionEngine, str, bool]:
    """(engine, engine method, foot lock) of a benchmark method or stand-in key."""
    if method == "som":
        return engines["som"], "upm", False
    if method in VARIANTS:
        return engines["fixed"], "upm", False
    base, feet = method_spec(method)
    return engines["upm"], base, feet
