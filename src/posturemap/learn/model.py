"""PostureMap: the four class maps, the skeleton and the feature space; map files.

A map file is a ``.npz`` archive without pickles: a ``meta`` entry holding UTF-8 JSON (format
name, version, skeleton, feature configuration, class assignment, training parameters and
quality figures) and plain numeric arrays (per class: weights, edges, hits, witness samples,
periods; the feature space's reference rotations, fill values and active dimensions; the
motion library's arrays). The format and its validation are in :mod:`posturemap.io.mapfile`;
files are written atomically (:func:`posturemap.io.fileio.write_bytes_atomic`).
"""

from __future__ import annotations

import io
import json
import os
import warnings
import zipfile
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import features
from ..io import mapfile
from ..errors import UserError
from .features import CLASSES, FeatureSpace
from ..io.fileio import write_bytes_atomic
from ..io.mapfile import FORMAT, VERSION, MapFileError  # noqa: F401 - MapFileError re-exported
from ..core.glitches import steady_motion
from ..core.joints import describe_legs
from ..core.motion import Motion, same_fps
from ..core.skeleton import Skeleton
from .upm import UniformPostureMap


class PostureMap:
    """Four Uniform Posture Maps (body, global, medium, detail) over one skeleton.

    Parameters
    ----------
    radius : float or "auto"
        Radius of every class map (``auto``: per class, see :func:`posturemap.learn.upm.auto_radius`).
    neighborhood, learning_rate, epochs, seed :
        As for :class:`~posturemap.learn.upm.UniformPostureMap`.
    features : "logmap" or "euler"
        Posture feature mode (see :mod:`posturemap.learn.features`).
    classes : dict or None
        Joint name to class name overrides.
    library : True, "recorded" or False
        Keep the training motion for retrieval transitions (:mod:`posturemap.synth.library`): True
        searches every clip as recorded and played backwards, "recorded" only as recorded.

    Attributes (after ``fit``)
    --------------------------
    skeleton_ : Skeleton
    space_ : FeatureSpace
    maps_ : list of 4 UniformPostureMap
    info_ : dict, training summary (clips, frames, seconds, quality per class)
    library_ : MotionLibrary or None, the training motion indexed by the ``global`` map
    """

    def __init__(self, radius="auto", neighborhood=2, learning_rate=0.5, epochs=4, seed=0,
                 features="logmap", classes=None, library=True):
        self.radius = radius
        self.neighborhood = neighborhood
        self.learning_rate = learning_rate
        self.epochs = epochs
        self.seed = seed
        self.features = features
        self.classes = classes
        self.library = library

    def fit(self, motions: list[Motion], names: list[str] | None = None, progress=None) -> "PostureMap":
        """Learn the four class maps from training motions (a list, or one Motion; one
        skeleton); returns ``self``.

        ``progress(class_name, epoch, epochs, n_neurons)`` is called as training advances.
        """
        import time

        motions = [motions] if isinstance(motions, Motion) else list(motions)
        if not motions:
            raise ValueError("no training motions")
        for m in motions:
            if not isinstance(m, Motion):
                raise TypeError(f"fit takes Motion objects (read files with posturemap.io.bvh.read), got "
                                f"{type(m).__name__}")
        names = names or [f"clip {i}" for i in range(len(motions))]
        first = motions[0].skeleton
        for name, m in zip(names, motions):
            m.check_usable(name)
            if not m.skeleton.same_as(first):
                raise UserError(name, f"skeleton differs from {names[0]} ({m.skeleton.difference(first, 'its')}; "
                                      "a map needs one skeleton)")
            why = m.skeleton.body_mismatch(first, f"{names[0]}'s")
            if why:
                raise UserError(name, f"{why}: a map needs one unit")
            if not same_fps(m.fps, motions[0].fps):
                raise UserError(name, f"{m.fps:g} fps, {names[0]} {motions[0].fps:g} fps (a map needs one frame "
                                      "rate: resample the clips to one rate first, posturemap.resample or "
                                      "posturemap resample)")
        t0 = time.perf_counter()
        motions = [steady_motion(m) for m in motions]  # a flipped toe is no posture to learn
        space = features.fit_space(motions, self.features, self.classes)
        x = np.concatenate([space.encode(m) for m in motions])
        seq = np.concatenate([np.full(len(m), i) for i, m in enumerate(motions)])
        parts = space.split(x)
        circ = space.circular
        maps = []
        for c in range(len(CLASSES)):
            period = np.where(circ[space.class_dims[c]], 2 * np.pi, np.inf)
            maps.append(UniformPostureMap(self.radius, self.neighborhood, self.learning_rate,
                                          self.epochs, self.seed + c, period))

        def train(c):
            cb = None
            if progress is not None:
                cb = lambda e, n, err: progress(CLASSES[c], e, int(self.epochs), n)  # noqa: E731
            return maps[c].fit(parts[c], seq, cb)

        with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
            list(pool.map(train, range(len(CLASSES))))
        self.skeleton_ = first
        self.space_ = space
        self.maps_ = maps
        if self.library not in (True, False, "recorded"):
            raise ValueError(f"library must be True, False or 'recorded', got {self.library!r}")
        self.library_ = self._build_library(motions, names) if self.library else None
        self.info_ = {
            "clips": len(motions), "frames": int(len(x)), "fps": float(motions[0].fps),
            "train_seconds": round(time.perf_counter() - t0, 3),
            "quality": {CLASSES[c]: {
                "neurons": m.n_neurons, "dims": int(parts[c].shape[1]), "radius": m.radius_,
                "quantization_error": m.quantization_error_,
                "topographic_error": m.topographic_error_,
                "invalid_neurons": m.invalid_fraction_,
                "edges": int(len(m.edges_)),
            } for c, m in enumerate(maps)},
        }
        return self

    def partial_fit(self, motions: list[Motion], names: list[str] | None = None, progress=None) -> "PostureMap":
        """Grow the fitted maps with more motions (a list, or one Motion; same skeleton and
        fps); returns ``self``.

        The feature space stays the one ``fit`` chose; each class map grows as
        :meth:`UniformPostureMap.partial_fit` does (neurons adapt, samples beyond the radius
        become new neurons). The new clips join the motion library, indexed by the grown map;
        the earlier clips keep the index entries they had (their winners when they were added:
        retrieval re-ranks every candidate exactly, so a neuron that moved since costs recall,
        not correctness; ``fit`` on all clips gives the exact index). Unfitted, this is ``fit``.
        The quality figures in ``info_`` are then those of the latest call's clips (as
        :meth:`UniformPostureMap.partial_fit` measures them).
        """
        motions = [motions] if isinstance(motions, Motion) else list(motions)
        if not hasattr(self, "maps_"):
            return self.fit(motions, names, progress)
        if not motions:
            raise ValueError("no training motions")
        info = self.info_ if isinstance(getattr(self, "info_", None), dict) else {}
        done = int(info.get("clips", 0))
        names = list(names) if names is not None else [f"clip {done + i}" for i in range(len(motions))]
        if len(names) != len(motions):
            raise ValueError(f"{len(names)} names for {len(motions)} motions")
        lib = getattr(self, "library_", None)
        fps = float(info.get("fps") or (lib.fps if lib is not None else motions[0].fps))
        for name, m in zip(names, motions, strict=True):
            if not isinstance(m, Motion):
                raise TypeError(f"partial_fit takes Motion objects (read files with posturemap.io.bvh.read), got "
                                f"{type(m).__name__}")
            m.check_usable(name)
            self.check_skeleton(m.skeleton, name)
            if not same_fps(m.fps, fps):
                raise UserError(name, f"{m.fps:g} fps, the map's clips {fps:g} fps: resample it to their rate first "
                                     "(posturemap.resample; on the command line, posturemap resample)")
        motions = [steady_motion(m) for m in motions]  # as fit reads them
        parts = self.space_.split(np.concatenate([self.space_.encode(m) for m in motions]))
        seq = np.concatenate([np.full(len(m), i) for i, m in enumerate(motions)])
        for c, m in enumerate(self.maps_):
            cb = None
            if progress is not None:
                cb = lambda e, n, err, c=c: progress(CLASSES[c], e, int(self.epochs), n)  # noqa: E731
            m.partial_fit(parts[c], seq, cb)
        if lib is not None:
            self.library_ = lib.joined(self._build_library(motions, names))
        info["clips"] = done + len(motions)
        info["frames"] = int(info.get("frames", 0)) + int(len(seq))
        info["fps"] = fps
        quality = info.setdefault("quality", {})
        for c, m in enumerate(self.maps_):
            quality.setdefault(CLASSES[c], {}).update(
                neurons=m.n_neurons, quantization_error=m.quantization_error_,
                topographic_error=m.topographic_error_, invalid_neurons=m.invalid_fraction_, edges=int(len(m.edges_)))
        self.info_ = info
        return self

    def predict(self, motion: Motion) -> np.ndarray:
        """The winning neuron of each frame in each class map: int array (F, 4), columns in
        :data:`~posturemap.learn.features.CLASSES` order."""
        x = self.encode(motion)  # first: it says so when the map is not fitted
        parts = self.space_.split(x)
        return np.stack([m.predict(x) for m, x in zip(self.maps_, parts)], axis=1)

    def score(self, motions) -> float:
        """How well the maps cover ``motions`` (a Motion or a list): minus the mean distance of
        their postures to the nearest neuron, in map radii, averaged over the four classes
        (higher is better, 0 when every posture is a neuron; above -1 means within one radius)."""
        motions = [motions] if isinstance(motions, Motion) else list(motions)
        x = np.concatenate([self.encode(m) for m in motions])  # encode says so when not fitted
        parts = self.space_.split(x)
        return -float(np.mean([m.quantization_error(x) / m.radius_ for m, x in zip(self.maps_, parts)]))

    def _build_library(self, motions, names):
        from ..synth.library import build_library
        from ..synth.engine import TransitionEngine

        engine = TransitionEngine(self)
        tracks = [engine.add(str(i), m) for i, m in enumerate(motions)]
        return build_library(tracks, self, [str(n) for n in names], reverse=self.library is True)

    # -- use ------------------------------------------------------------------------------
    def encode(self, motion: Motion) -> np.ndarray:
        """Full posture vectors of a motion with this map's skeleton, (F, D); a
        :class:`UserError` for a clip of no frames or with a NaN or infinite value."""
        self.require_fitted()
        motion.check_usable("motion")
        self.check_skeleton(motion.skeleton, "motion")
        return self.space_.encode(motion)

    def check_skeleton(self, sk: Skeleton, where: str):
        """A :class:`UserError` on ``where`` unless ``sk`` is the map's skeleton: its joints,
        hierarchy and channels, in the map's unit (:meth:`Skeleton.body_mismatch`)."""
        if not sk.same_as(self.skeleton_):
            diff = sk.difference(self.skeleton_, "the map's")
            raise UserError(where, f"skeleton differs from the map's ({diff})")
        why = sk.body_mismatch(self.skeleton_, "the map's")
        if why:
            raise UserError(where, f"{why}: a map holds one unit; rescale the clip or train a map on clips like it")

    def neuron_counts(self) -> list[int]:
        return [m.n_neurons for m in self.maps_]

    # -- files ----------------------------------------------------------------------------
    def require_fitted(self) -> None:
        """Raise a ``ValueError`` unless the map was fitted or loaded."""
        if getattr(self, "skeleton_", None) is None:
            raise ValueError("the posture map is not fitted: fit it on clips or load a map file first")

    def save(self, path: str) -> None:
        """Write the map to ``path`` (.npz, no pickle) atomically; a folder that is missing or
        not writable, a full disk and the like raise :class:`UserError` naming the file (an
        existing file stays as it was)."""
        self.require_fitted()
        meta = {
            "format": FORMAT, "version": VERSION,
            "skeleton": self.skeleton_.to_dict(),
            "space": self.space_.to_dict(),
            "classes": list(CLASSES),
            "assignment": {n: CLASSES[c] for n, c in zip(self.skeleton_.names, self.space_.joint_class)},
            "params": {"radius": self.radius, "neighborhood": self.neighborhood,
                       "learning_rate": self.learning_rate, "epochs": self.epochs, "seed": self.seed,
                       "features": self.features},
            "radius": [m.radius_ for m in self.maps_],
            "info": self.info_,
        }
        lib = getattr(self, "library_", None)
        if lib is not None:
            meta["library"] = lib.meta()
        arrays = {"meta": np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)}
        for k, v in self.space_.arrays().items():
            arrays[f"space_{k}"] = v
        for c, m in enumerate(self.maps_):
            arrays[f"c{c}_weights"] = m.weights_
            arrays[f"c{c}_edges"] = m.edges_.astype(np.int64).reshape(-1, 2)
            arrays[f"c{c}_hits"] = m.hits_
            arrays[f"c{c}_witness"] = m.witness_
            arrays[f"c{c}_period"] = m.period_
        if lib is not None:
            for k, v in lib.arrays().items():
                arrays[f"library_{k}"] = v
        # An .npz archive: the maps compressed, the motion library stored as is (it hardly
        # compresses, and reading it without inflating keeps a CLI transition quick).
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w") as zf:
            for name, arr in arrays.items():
                member = io.BytesIO()
                np.lib.format.write_array(member, np.asanyarray(arr), allow_pickle=False)
                zf.writestr(name + ".npy", member.getvalue(),
                            zipfile.ZIP_STORED if name.startswith("library_") else zipfile.ZIP_DEFLATED)
        try:
            write_bytes_atomic(path, buf.getvalue())
        except OSError as e:
            raise UserError(os.fspath(path), f"cannot write file ({e.strerror or e})") from None

    @classmethod
    def load(cls, path: str) -> "PostureMap":
        """Read a map file; a corrupt, truncated, foreign or hostile file raises :class:`MapFileError`.

        Every metadata field and array is checked first (:func:`posturemap.io.mapfile.read`).
        """
        path = os.fspath(path)
        meta, arrays = mapfile.read(path)
        try:
            with warnings.catch_warnings():  # e.g. a cast of huge values: a corrupt file, not a warning
                warnings.simplefilter("error", RuntimeWarning)
                return cls._from_parts(meta, arrays)
        except (KeyError, TypeError, ValueError, IndexError, RuntimeWarning) as e:
            if getattr(e, "sound_file", False):  # read otherwise by this version (synth.library.EarlierLegs)
                raise MapFileError(path, str(e)) from None
            raise MapFileError(path, f"corrupt map file ({type(e).__name__}: {e})") from None

    @classmethod
    def _from_parts(cls, meta: dict, arrays: dict) -> "PostureMap":
        """A map from metadata and arrays checked by :func:`posturemap.io.mapfile.read`."""
        p = meta["params"]
        self = cls(p["radius"], p["neighborhood"], p["learning_rate"], p["epochs"], p["seed"], p["features"])
        self.skeleton_ = Skeleton.from_dict(meta["skeleton"])
        self.space_ = FeatureSpace.from_parts(meta["space"], {k[6:]: v for k, v in arrays.items()
                                                               if k.startswith("space_")})
        self.maps_ = []
        for c in range(len(CLASSES)):
            w = np.asarray(arrays[f"c{c}_weights"], dtype=np.float64)
            edges = np.asarray(arrays[f"c{c}_edges"], dtype=np.int64)
            period = np.asarray(arrays[f"c{c}_period"], dtype=np.float64)
            m = UniformPostureMap(meta["radius"][c], p["neighborhood"], p["learning_rate"], p["epochs"],
                                  p["seed"] + c, period)
            m.weights_, m.edges_, m.period_ = w, edges, period
            m.hits_ = np.asarray(arrays[f"c{c}_hits"], dtype=np.int64)
            m.witness_ = np.asarray(arrays[f"c{c}_witness"], dtype=np.int64)
            m.radius_ = float(meta["radius"][c])
            self.maps_.append(m)
        self.info_ = meta.get("info", {})
        self.library_ = None
        if "library" in meta:
            from ..synth.library import MotionLibrary

            if not isinstance(meta["library"], dict):
                raise ValueError("library metadata is not an object")
            lib_arrays = {k[8:]: v for k, v in arrays.items() if k.startswith("library_")}
            self.library_ = MotionLibrary.from_parts(meta["library"], lib_arrays, self.skeleton_,
                                                     self.maps_[1].n_neurons)
        self.library = False if self.library_ is None else (True if self.library_.reverse else "recorded")
        return self

    def _toe_clearance(self) -> dict | None:
        """The library's swinging-toe clearance for :meth:`describe`: ``{"speeds", "heights"}`` in
        leg lengths (per second), or None (no toe counts: a rig without toes, an older file)."""
        curve = self.library_.clearance
        if curve is None:
            return None
        from ..synth.feet import clearance_speeds

        return {"speeds": [round(float(v), 3) for v in clearance_speeds()],
                "heights": [round(float(h), 4) for h in curve]}

    def describe(self) -> dict:
        """JSON-ready summary: neurons per class, parameters, quality, class assignment."""
        return {
            "skeleton": {"joints": self.skeleton_.num_joints, "root": self.skeleton_.names[self.space_.root],
                         "up": "XYZ"[self.space_.up]},
            "features": self.space_.mode,
            "params": {"radius": self.radius, "neighborhood": self.neighborhood,
                       "learning_rate": self.learning_rate, "epochs": self.epochs, "seed": self.seed},
            "classes": {CLASSES[c]: {"neurons": m.n_neurons, "dims": int(m.weights_.shape[1]),
                                     "radius": m.radius_, "edges": int(len(m.edges_)),
                                     **{k: v for k, v in self.info_.get("quality", {}).get(CLASSES[c], {}).items()
                                        if k in ("quantization_error", "topographic_error", "invalid_neurons")}}
                        for c, m in enumerate(self.maps_)},
            "training": {k: v for k, v in self.info_.items() if k != "quality"},
            "assignment": {CLASSES[c]: [n for n, jc in zip(self.skeleton_.names, self.space_.joint_class) if jc == c]
                           for c in range(len(CLASSES))},
            "legs": describe_legs(self.skeleton_),
            "library": None if self.library_ is None else {
                **{k: v for k, v in self.library_.meta().items() if k != "clips"},
                "clips": self.library_.num_recorded_clips,
                "key_joints": [self.skeleton_.names[j] for j in np.concatenate([self.library_.lower,
                                                                                self.library_.upper])],
                "toe_clearance": self._toe_clearance()},
        }
