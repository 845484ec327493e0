"""``posturemap bench``: in-betweening accuracy, realism and speed of every method, on hold-outs.

Modules: :mod:`.protocol` (hold-outs, splits, windows, methods, settings), :mod:`.baselines`
(the classic SOM key and other stand-in keys), :mod:`.scoring` (metrics of rebuilt windows),
:mod:`.runner` (the run), :mod:`.speed` (latency, training, ``bench/`` scripts) and
:mod:`.report` (results.md and the plots, from the results dict alone).

Protocol (the project's design contract, "Evaluation protocol"; LaFAN1 benchmark of Harvey et al. 2020)
---------------------------------------------------------------------------------------
Three hold-outs (:data:`HOLDOUTS`), each evaluated separately; for each, the posture map (and
whatever a method keeps from the training clips, e.g. a motion library), the classic SOM, the
L2P statistics, the feet's planted heights and the pose-validity index are built from that
hold-out's training side only:

- ``style``: Bandai-Namco dataset-1 (``bandai1/dataset-1_{content}_{style}_{id}.bvh``); test =
  every clip of the styles :data:`TEST_STYLES` (angry, old, proud; 33 clips, every content),
  training = the other 141 clips. Unseen performers' styles of known motion types.
- ``content``: test = every clip of the contents :data:`TEST_CONTENTS` (dash, walk-back,
  byebye: fast locomotion, walking backwards, a waving gesture; 45 clips, every style),
  training = the other contents (129 clips). Whole motion types absent from the library.
- ``cmu``: CMU subject 1, trial 1 (``cmu/01_01.bvh``, 120 fps, its own skeleton and unit):
  training = the first half of its frames, test = the second half; lengths
  :data:`CMU_LENGTHS`, the same frame counts as at 30 fps and the same durations (x 4).

``--quick`` (:meth:`Settings.quick_run`, about 20 s on 2 idle cores): every fourth training
clip (sorted by name), 8 seeded random test windows per hold-out, 10 cross-clip pairs, a
quarter of a MiniSom epoch, 100 latency calls, no diagnostics, no sweep and no ``bench/``
scripts; every method, metric and hold-out still runs.

In-betweening: from each test clip, windows of 10 + max(L) + 10 frames start every 40 frames
(LaFAN1: ``while start + window < frames``); for a transition length L the window's first 10 +
L + 10 frames are used (as LaFAN1 does): 10 past-context frames, L frames to rebuild, 10
future-context frames. Every method sees the context only: the engine gets the 10 past frames
as clip A and the 10 future frames as clip B (``a_end`` = A's last frame, ``b_start`` = 0,
``align=False``: the truth's root trajectory is the reference), so no method can read a frame
of the gap. Methods (:data:`METHODS`):

- ``zero-velocity``: holds the last past-context frame (local rotations and root position);
- every method of :data:`posturemap.synth.engine.METHODS` (new ones join automatically), through
  :class:`TransitionEngine` on a map fitted on the hold-out's training clips; ``+feet``
  (:data:`FEET`) variants for ``upm-valid`` and the default method;
- ``som``: ``upm`` with the key taken from a classic fixed-grid SOM (MiniSom) per bone class,
  with about the neuron count of the UPM class map (:func:`som_grid`), trained on the same
  features; the key is the SOM neuron nearest the alpha-blend, then the same B-spline.

Metrics (:mod:`posturemap.evaluate.metrics`) on the rebuilt frames, per method and length, overall and
per motion type (content): L2Q, L2P, NPSS (LaFAN1), MPJPE, root position error and
root-relative joint position error (cm); foot skate, the standard height-weighted measure
(:func:`posturemap.evaluate.metrics.weighted_skate`, cm/s, H = 2.5 cm per 80 cm of leg, ground = the
lowest foot joint over the window, over the L + 1 frame steps from the last past-context
frame to the first future-context frame; no contact detection), with the older contact-based
measure as a secondary column (``contact_skate``); floor penetration
(:func:`posturemap.evaluate.metrics.floor_penetration`, cm: the deepest foot joint under the
floor, the lowest foot joint in the context frames, averaged over the gap); feet off the floor
(:func:`posturemap.evaluate.metrics.foot_float`, cm: how far the lowest foot joint rises in the
gap above the highest it reaches in the context frames, which the height-weighted skate cannot
see; between clips also the count of transitions over 10 cm); naturalness
(:func:`naturalness_fn`: each
rebuilt window's distance to its nearest real window of the same length among the test clips,
which no library has seen, leaving out windows that overlap its own frames; z-scored pose and
velocity features in the character's frame); pose validity (distance to the nearest training
posture in the map's feature space) and jerk (cm/s^3). Beside each realism figure, the truth's.
Every method against slerp, window by window, with a bootstrap interval.

A gap in a take (:data:`WHOLE_CLIP`, :func:`predict_whole_clip`): the same windows again for
the default, given the whole test clip but the gap as context (A up to the last past frame, B
from the first future frame), as it runs (the clips' own motion searched beside the library) and
with the library only; scored like the methods, on the hold-outs and the more splits.

More splits (:data:`MORE_SPLITS`, :func:`run_split`): four more splits of bandai1, two holding
out other whole styles (childish, giant, tired; chimpira, musical, sad) and two other whole
motion types (walk-left, run, bye; walk, guide), with the same protocol at 15, 30 and 45
frames, scored for the main methods (:data:`SPLIT_METHODS`: the baselines, the previous default
and the default) by L2Q, L2P and foot skate only; the report puts every Bandai split's ratios
to slerp (and the skate's to the truth's) side by side, with their mean. One split can flatter
a rule developed on it; six are harder to flatter.

Cross-clip transitions (hold-outs with two or more test clips): seeded random pairs of two
different test clips, random ``a_end`` and ``b_start``, ``length`` 20 (the paper's),
``align=True``. No ground truth: foot skate, validity and jerk, next to the same figures on the
real frames around the seams.

Diagnostics for the keyed methods (style hold-out, full run): distance of the key posture to
the true posture at ``key_at`` (next to the alpha-blend's, A's and B's and the nearest
neuron's), overall and per bone class; stand-ins (:data:`VARIANTS`) through the same spline;
a sweep of ``alpha`` and ``key_at``.

A user's own clips (``posturemap bench --train INPUT... --test INPUT...``; :func:`load_own`,
:func:`run_own`): one hold-out, ``own``, with the library from the training clips and the gaps
cut from the test clips as above, at the bench's durations (5, 15, 30 and 45 frames at 30 fps,
as long at the test clips' rate) or ``--lengths``; every method and metric, the per-motion tables
by the input each test clip came from, the speed on its map; no Bandai split, no ``bench/``
script.

Speed (on the style hold-out's map): per-method latency of :meth:`TransitionEngine.generate`
(median, p99), UPM training against MiniSom at equal neuron count (samples/s), and the scripts
in the repository's ``bench/`` folder when present (BVH loading against other readers, ...).
"""

from . import report
from .baselines import (KeyModel, KeyTable, centred, engine_call, fixed_key_model, grid_edges, set_key, som_grid,
                        som_model, train_som)
from .protocol import (ASF_UNIT_CM, CMU_FILE, CMU_LENGTHS, CROSS_LENGTH, DEFAULT_SPEC, FEET, FLOOR_PERCENTILE,
                       HOLDOUTS, LENGTHS, METHODS, MORE_SPLITS, N_FUTURE, N_PAST, OWN, OWN_LENGTHS_30, QUALITY_KEYS,
                       SPLIT_LENGTHS,
                       SPLIT_METHODS, STATS_STRIDE,
                       STATS_WINDOW, STRIDE, SWEEP_FRACTIONS, SWEEP_LENGTHS, TEST_CONTENTS, TEST_STYLES, UNIT_CM,
                       VARIANTS, WHOLE_CLIP, Settings, Split, load_own, load_split, make_windows, method_spec, own_lengths,
                       parse_name,
                       random_pairs, split_files, unit_cm, window_starts)
from .runner import (clips_in, code_version, default_data_dir, empty_engines, generate_from_context,
                     make_engines, predict_whole_clip, predict_windows, prepare, round_per_window, run, run_cli, run_own,
                     run_cross,
                     run_diagnostics, run_holdout, run_inbetween, run_split, sweep)
from .scoring import (NATURAL_FRAMES, NATURAL_STRIDE_S, PER_CONTENT_KEYS, Context, global_windows,
                      natural_frames, natural_reference, naturalness_fn, paired_difference, per_content,
                      rebuilt_frames, score_inbetween, score_truth, skate_scores, truth_globals, window_features)
from .speed import bench_dir, latency, run_bench_script, training_speed

__all__ = ["report", "KeyModel", "KeyTable", "centred", "engine_call", "fixed_key_model", "grid_edges",
           "set_key", "som_grid", "som_model", "train_som", "ASF_UNIT_CM", "CMU_FILE", "CMU_LENGTHS",
           "CROSS_LENGTH", "DEFAULT_SPEC", "FEET", "FLOOR_PERCENTILE", "HOLDOUTS",
           "LENGTHS", "METHODS", "MORE_SPLITS", "N_FUTURE", "N_PAST", "OWN", "OWN_LENGTHS_30", "SPLIT_LENGTHS",
           "SPLIT_METHODS",
           "QUALITY_KEYS", "STATS_STRIDE", "STATS_WINDOW",
           "STRIDE", "SWEEP_FRACTIONS", "SWEEP_LENGTHS", "TEST_CONTENTS", "TEST_STYLES", "UNIT_CM",
           "VARIANTS", "WHOLE_CLIP", "Settings", "Split", "load_own", "load_split", "make_windows", "method_spec",
           "own_lengths",
           "parse_name", "random_pairs", "split_files", "unit_cm", "window_starts", "code_version",
           "default_data_dir", "generate_from_context", "clips_in", "empty_engines", "round_per_window",
           "make_engines", "predict_whole_clip", "predict_windows", "prepare", "run", "run_cli", "run_own", "run_cross",
           "run_diagnostics",
           "run_holdout", "run_inbetween", "run_split", "sweep", "NATURAL_FRAMES", "NATURAL_STRIDE_S",
           "PER_CONTENT_KEYS", "Context",
           "global_windows", "natural_frames", "natural_reference", "naturalness_fn", "paired_difference",
           "per_content", "rebuilt_frames", "score_inbetween", "score_truth", "skate_scores",
           "truth_globals", "window_features", "bench_dir", "latency", "run_bench_script", "training_speed"]
