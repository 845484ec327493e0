"""The ``posturemap`` command: parses arguments and calls the library (thin by design)."""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys

from . import __version__
from .errors import UserError, require_extra
from .learn.limits import MAX_EPOCHS, MAX_NEIGHBORHOOD, MAX_RADIUS, MAX_SEED
from .synth.request import DEFAULT_ALPHA, DEFAULT_LENGTH, DEFAULT_METHOD, MAX_LENGTH, METHOD_INFO, METHODS


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line on stderr and exit code 2 (no usage dump)."""

    def error(self, message):
        # argparse says "argument --length: ...": the option first, as the other errors name their file
        if message.startswith("argument ") and ": " in message:
            message = message[len("argument "):]
        sys.stderr.write(f"posturemap: error: {message}\n")
        sys.exit(2)


def _data_folder(given: str | None) -> str:
    """The data folder: ``--data``, else ``$POSTUREMAP_DATA``; never a guess inside the install."""
    data = given or os.environ.get("POSTUREMAP_DATA")
    if not data:
        raise UserError("--data", "no data folder: give --data DIR or set POSTUREMAP_DATA "
                                  "(a folder holding bandai1/ and cmu/01_01.bvh)")
    if not os.path.isdir(data):
        raise UserError(data, "data folder does not exist" + ("" if given else " (from POSTUREMAP_DATA)"))
    return data


def _cmd_bench(args) -> int:
    require_extra("bench", "minisom", "matplotlib", what="bench")
    if bool(args.train) != bool(args.test):
        raise UserError("--train" if args.test else "--test", "give both --train and --test (your own clips), "
                        "or neither (the bench's hold-outs of bandai1 and CMU)")
    if args.lengths and not args.train:
        raise UserError("--lengths", "only with --train and --test (the bench's hold-outs fix their gaps)")
    if args.data and args.train:
        raise UserError("--data", "not with --train and --test (they give the clips)")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise UserError(args.out, "is a file, expected the output folder")
    if not args.train:
        args.data = _data_folder(args.data)
    from . import evaluate
    from .core import kernels

    kernels.compiled()  # hundreds of files to read, maps to train, transitions to time
    return evaluate.run_cli(args)


def _cmd_serve(args) -> int:
    require_extra("web", "starlette", "uvicorn", what="serve")
    from .web import server
    return server.run_cli(args)


def _cmd_demo(args) -> int:
    from . import demo
    out = args.out or demo.default_out(args.data)
    demo.run(out, data=args.data, log=print)
    return 0


class _Progress:
    """One status line per training run: epoch and neurons per class (stderr)."""

    def __init__(self, epochs: int, stream=None):
        self.epochs, self.stream = epochs, stream or sys.stderr
        self.state: dict[str, tuple[int, int]] = {}
        self.tty = self.stream.isatty()

    def __call__(self, cls: str, epoch: int, epochs: int, neurons: int):
        self.state[cls] = (epoch, neurons)
        done = min(e for e, _ in self.state.values()) if len(self.state) == 4 else 0
        if not self.tty and done == getattr(self, "_shown", -1):
            return
        self._shown = done
        width = 20
        bar = "#" * int(width * done / self.epochs) + "-" * (width - int(width * done / self.epochs))
        parts = "  ".join(f"{c} {n}" for c, (_, n) in sorted(self.state.items()))
        line = f"training [{bar}] epoch {done}/{self.epochs}  neurons: {parts}"
        self.stream.write("\r" + line if self.tty else line + "\n")
        self.stream.flush()

    def close(self):
        if self.tty:
            self.stream.write("\n")


def _checked(convert, ok, rule: str):
    """An argparse type: ``convert`` the text, then require ``ok(value)``; else say ``rule``."""
    def parse(text: str):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}") from None
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        return value
    return parse


_positive_int = _checked(int, lambda v: v >= 1, "a whole number of at least 1")
_nonneg_int = _checked(int, lambda v: v >= 0, "a whole number, not negative")
_gain = _checked(float, lambda v: 0.0 < v < 1.0, "a number between 0 and 1 (exclusive)")
_positive = _checked(float, lambda v: 0 < v <= MAX_RADIUS, f"a positive number up to {MAX_RADIUS:g} or 'auto'")
_hops = _checked(int, lambda v: 0 <= v <= MAX_NEIGHBORHOOD, f"a whole number from 0 to {MAX_NEIGHBORHOOD}")
_epochs = _checked(int, lambda v: 1 <= v <= MAX_EPOCHS, f"a whole number from 1 to {MAX_EPOCHS}")
_seed = _checked(int, lambda v: 0 <= v <= MAX_SEED, f"a whole number from 0 to {MAX_SEED}")
_gaps = _checked(lambda t: tuple(int(x) for x in t.split(",")), lambda v: all(1 <= n <= MAX_LENGTH for n in v),
                 f"comma-separated whole numbers from 1 to {MAX_LENGTH}")


def _radius(text: str):
    return "auto" if text == "auto" else _positive(text)


def _cmd_train(args) -> int:
    from .core import kernels
    from .core.motion import at_one_rate, resampled_name, resampled_note
    from .io.bvh import read_inputs
    from .learn.features import load_class_overrides
    from .learn.model import PostureMap

    if not args.output.lower().endswith(".npz"):
        raise UserError(args.output, "a map's name must end in .npz")
    _check_output(args.output, args.inputs)
    kernels.compiled()  # training needs them; reading many files is faster with them too
    clips = read_inputs(args.inputs)
    paths = [p for p, _ in clips]
    motions, changed = at_one_rate([m for _, m in clips], names=paths)
    for i in changed:  # a map's clips share one rate: the first clip's
        print(resampled_note(clips[i][0], clips[i][1].fps, motions[0].fps), file=sys.stderr)
        # Its frames in the library (and in a transition's report) are at that rate: said in its name.
        paths[i] = resampled_name(paths[i], motions[0].fps)
    _warn_odd_inputs(paths, motions)
    classes = load_class_overrides(args.classes, clips[0][1].skeleton.names) if args.classes else None
    progress = _Progress(args.epochs)
    pm = PostureMap(args.radius, args.neighborhood, args.learning_rate, args.epochs, args.seed,
                    args.features, classes)
    try:
        pm.fit(motions, paths, progress=progress)
    finally:
        progress.close()
    pm.save(args.output)
    info = pm.info_
    print(f"{args.output}: {info['clips']} clips, {info['frames']} frames, "
          f"{sum(pm.neuron_counts())} neurons ("
          + ", ".join(f"{c} {q['neurons']}" for c, q in info["quality"].items())
          + f"), trained in {info['train_seconds']:.1f} s")
    return 0


def _warn_odd_inputs(paths: list[str], motions) -> None:
    """Warn (on stderr) of a training clip given twice (its frames would count twice in the maps
    and the library) and of clips whose body stands along another axis than most clips' (the
    map takes the axis most frames stand along: a clip lying on the floor reads as another axis,
    a clip of another convention would be mixed up)."""
    from .core.motion import shared_up_axis

    seen = {}
    for p in paths:
        key = os.path.realpath(p)
        if key in seen:
            also = "" if seen[key] == p else f" (as {seen[key]})"
            print(f"posturemap: warning: {p}: given twice{also}: its frames count twice in the map", file=sys.stderr)
        seen.setdefault(key, p)
    up, axes = shared_up_axis(motions)
    for p, a in zip(paths, axes):
        if a != up:
            print(f"posturemap: warning: {p}: the body stands along {'XYZ'[a]}, most clips' along {'XYZ'[up]} "
                  f"(the map's up axis): lying on the floor, or of another up axis?", file=sys.stderr)


def _check_output(path: str, inputs=()):
    """Refuse an output whose folder is missing, that is a folder, or that is one of the
    command's ``inputs`` (writing it would replace a file the command reads)."""
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UserError(path, "output folder does not exist")
    if os.path.isdir(path):
        raise UserError(path, "is a folder, expected a file name")
    for source in inputs:
        try:
            same = os.path.samefile(path, source)
        except OSError:  # either missing (the output is new) or unreadable (the input's read says so)
            same = False
        if same:
            raise UserError(path, f"is an input of this command ({source}); write the output to another file")


def _is_gltf_output(path: str) -> bool:
    """Whether ``path`` asks for glTF (.glb, .gltf) rather than BVH (.bvh); any other ending is
    a :class:`UserError` (the ending sets the format)."""
    from .io import gltf

    if gltf.is_gltf_path(path):
        return True
    if not path.lower().endswith(".bvh"):
        raise UserError(path, "the output's name must end in .bvh, .glb or .gltf (it sets the format)")
    return False


def _cmd_transition(args) -> int:
    from .io import bvh, gltf
    from .learn.model import PostureMap
    from .core.motion import at_one_rate, resampled_name, same_fps, up_axis
    from .synth.engine import transition
    from .synth.request import KEYED, RequestError, TransitionRequest, frame_index
    from .core.joints import leg_chains

    as_gltf = _is_gltf_output(args.output)
    if args.split_animations and not as_gltf:
        raise UserError("--split-animations", "needs a glTF output (-o ending in .glb or .gltf)")
    if args.preview:
        require_extra("preview", "matplotlib", what="--preview")
        if not args.preview.lower().endswith(".png"):
            raise UserError(args.preview, "a preview file name must end in .png")
        _check_output(args.preview, [args.a, args.b])
    a = bvh.read(args.a)
    one_take = _same_file(args.a, args.b)
    b = a if one_take else bvh.read(args.b)  # a take: read and steadied once
    if not b.skeleton.same_as(a.skeleton):
        raise UserError(args.b, f"skeleton differs from {args.a} ({b.skeleton.difference(a.skeleton, 'its')})")
    why = b.skeleton.body_mismatch(a.skeleton, f"{args.a}'s")
    if why:
        raise UserError(args.b, why)
    _check_output(args.output, [args.a, args.b])
    b_start, rate_note, b_name = args.b_start, None, args.b
    if not same_fps(a.fps, b.fps):  # B at A's rate; --b-start counts B's own frames
        try:
            frame_index("b_start", b_start, len(b), "clip B")
        except RequestError as e:
            raise UserError("--b-start", e.what) from None
        # From its frame b_start on only: a resampled frame between two of B's would blend in the
        # frame before b_start, which a gap in a take (B the take at another rate) replaces.
        b_fps, b = b.fps, at_one_rate([b[args.b_start:]], a.fps, [args.b])[0][0]
        b_start = 0
        rate_note = (f"  {args.b}: {b_fps:g} fps, its frames from {args.b_start} on resampled to A's {a.fps:g} fps "
                     f"(its frame {args.b_start} is their first)")
        # The report counts them from there, at A's rate.
        b_name = f"{resampled_name(args.b, a.fps)} from its frame {args.b_start}"
    model = None
    if args.map:
        model = PostureMap.load(args.map)
        model.check_skeleton(a.skeleton, args.a)
    given = model is not None
    gap = args.b_start - args.a_end - 1 if args.a_end is not None else 0
    if args.no_align and gap > 0 and args.length != gap and rate_note is None and one_take:
        print(f"posturemap: warning: {args.b}: A and B are one take and --length {args.length} is not the {gap} frames "
              f"between --a-end and --b-start: the take comes out {abs(gap - args.length)} frames "
              f"{'shorter' if args.length < gap else 'longer'} (--length {gap} keeps its duration)", file=sys.stderr)
    request = TransitionRequest(length=args.length, alpha=args.alpha, method=args.method, key_at=args.key_at,
                                a_end=args.a_end, b_start=b_start, align=not args.no_align,
                                foot_lock=not args.no_foot_lock)
    try:
        request = request.resolved(len(a), len(b))
    except RequestError as e:  # shown as the option that set the field
        raise UserError("--" + e.field.replace("_", "-"), e.what) from None
    if model is None and args.method in KEYED:
        # Learned from the frames the output keeps, A's to its end and B's from its start, and
        # without a motion library: the motion replayed is those frames' own (see
        # engine._own_retriever). A gap in one take (A and B the same file) is never read,
        # so its frames cannot come back as the transition.
        model = PostureMap(seed=0, library=False).fit([a[: request.a_end + 1], b[request.b_start:]], [args.a, args.b])
    # The same rig turned to another up axis passes the skeleton's check (its bones are the
    # same); the map's axis, or A's, would then turn B and plant the feet wrongly (a Y-up A and a
    # Z-up B: B lay on the floor). Read from the body's extent, which a clip lying on the floor
    # can mislead: a warning, as the studio's. Against the axis the transition takes: the map's
    # (one made of A and B takes the one most of their frames stand along), else A's.
    if given:
        ref, whose = model.space_.up, "the map's clips"
    elif model is not None:
        ref, whose = model.space_.up, f"{args.a} and {args.b} (most frames)"
    else:
        ref, whose = up_axis(a), f"{args.a}'s"
    for path, clip in ((args.a, a), (args.b, b)):
        up = up_axis(clip)
        if up != ref:
            print(f"posturemap: warning: {path}: the body stands along {'XYZ'[up]}, {whose} along {'XYZ'[ref]}: "
                  "the transition may not line up " + ("(a map trained on clips of this orientation would)" if given
                                                       else "(lying on the floor, or of another up axis?)"),
                  file=sys.stderr)
    _warn_seam_glitches(((args.a, a, request.a_end, "its last frame" if request.a_end == len(a) - 1 else
                          f"its frame {request.a_end}", f"--a-end {request.a_end - 1} ends A before it"
                          if request.a_end > 0 else None),
                         (args.b, b, request.b_start, f"its frame {args.b_start}",
                          f"--b-start {args.b_start + 1} starts B after it" if request.b_start + 1 < len(b) else None)))
    report = {}
    try:
        out = transition(a, b, model, request, report=report)
    except RequestError as e:  # shown as the option that set the field
        raise UserError("--" + e.field.replace("_", "-"), e.what) from None
    a_end = request.a_end
    used = report.get("method", args.method)
    # The filmstrip first (drawing it is what fails most), then the output; if that cannot be
    # written, a filmstrip this call made is removed again: an error leaves nothing new.
    made_preview = False
    if args.preview:
        from .io import preview
        from .core.motion import length_unit

        made_preview = not os.path.exists(args.preview)
        preview.transition_filmstrip(out, a_end + 1, args.length, args.preview,
                                     up=model.space_.up if model is not None else up_axis(out),
                                     title=f"{os.path.basename(args.a)} -> {os.path.basename(args.b)}: "
                                           f"{args.length} {used} frames", unit=length_unit(a))
    try:
        if as_gltf:
            stem = lambda p: os.path.splitext(os.path.basename(p))[0]  # noqa: E731
            gltf.write(args.output, out, parts=gltf.transition_parts(a_end + 1, args.length, len(out)),
                       split=args.split_animations, name=f"{stem(args.a)}_to_{stem(args.b)}",
                       up=model.space_.up if model is not None else None)
        else:
            bvh.write(args.output, out)
    except BaseException:
        if made_preview:
            with contextlib.suppress(OSError):
                os.remove(args.preview)
        raise
    b_part = (f"B[{b_start}..{len(b) - 1}]" if rate_note is None
              else f"B from its frame {args.b_start} ({len(b)} frames)")
    print(f"{args.output}: {len(out)} frames = A[0..{a_end}] + {args.length} {used} frames + {b_part}"
          + (f"; filmstrip {args.preview}" if args.preview else ""))
    if rate_note:
        print(rate_note)
    if "retrieval" in report:
        print(describe_retrieval(report["retrieval"], {"a": args.a, "b": b_name}))
    if not args.no_foot_lock and not leg_chains(a.skeleton):
        print(f"  foot lock: off, no legs found by name (an ankle named foot or ankle, under a shin and a thigh) "
              f"nor in the hierarchy (two like chains beside the spine; posturemap inspect {args.a} shows the "
              "skeleton)")
    return 0


def _warn_seam_glitches(seams) -> None:
    """A warning for each seam frame (``(path, clip, frame, what, way out)``) that is itself a
    glitch, as a map would learn the clip (:func:`posturemap.core.glitches.changed_joint`: a
    reference pose, a solver's flip): the new frames start from (land on) the frame as given, at
    the velocity of the frames beside it, so that they turn into it over the gap
    (:func:`posturemap.synth.trajectory.seam_view`)."""
    from .core.glitches import changed_joint, steady_motion

    steadied = {}  # one clip read once for A and B (a gap in a take) is steadied once
    for path, clip, frame, what, way_out in seams:
        if id(clip) not in steadied:
            steadied[id(clip)] = steady_motion(clip)
        found = changed_joint(clip, frame, steadied[id(clip)])
        if found is not None:
            j, angle = found
            print(f"posturemap: warning: {path}: {what} is a glitch at {clip.skeleton.names[j]} "
                  f"({math.degrees(angle):.0f} degrees off the frames beside it: a reference pose or a flipped "
                  "joint); the new frames turn into it over the gap" + (f" ({way_out})" if way_out else ""),
                  file=sys.stderr)


def _cmd_resample(args) -> int:
    from .io import bvh, gltf
    from .core.motion import resample

    as_gltf = _is_gltf_output(args.output)
    _check_output(args.output, [args.input])
    m = bvh.read(args.input)
    try:
        out = resample(m, args.fps)
    except ValueError as e:  # a result too large to hold
        raise UserError(args.input, str(e)) from None
    if as_gltf:
        gltf.write(args.output, out)
    else:
        bvh.write(args.output, out)
    print(f"{args.output}: {len(out)} frames at {out.fps:g} fps ({args.input}: {len(m)} frames at {m.fps:g} fps)")
    return 0


def _same_file(a: str, b: str) -> bool:
    """Whether two paths name one file."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def describe_retrieval(info, clips: dict | None = None) -> str:
    """One line per body part: which clip and frames were replayed, and how confidently.
    ``clips``: the files of the clips' own motion by their names in the report (``a``, ``b``)."""
    if not info:
        return ("  retrieval: no segment of the library or of the clips' own frames fits; interpolated instead "
                "(fallback)")
    if max(r["confidence"] for r in info["parts"].values()) <= 0.0:
        if info.get("standing"):
            return ("  retrieval: the body stands still at both seams (a standing gesture, confidence 0); "
                    "interpolated instead")
        return "  retrieval: the best segments match too loosely (confidence 0); interpolated instead"
    names = (clips or {}) if info.get("own") else {}

    def source(r):
        return (f"{names.get(r['clip'], r['clip'])} frames {r['frames'][0]}..{r['frames'][1]}"
                f"{' (played backwards)' if r['reversed'] else ''} "
                f"(warp {r['warp']:.2f}), match distance {r['distance']:.2f} degrees")

    lines = ["  retrieval: the clips' own motion (A's frames up to its end, B's from its start)"] if info.get("own") \
        else []
    for part, r in info["parts"].items():
        if "then" in r:  # a splice: the segment continuing A, blended into the one arriving in B
            lines.append(f"  {part}: {source(r)}, then {source(r['then'])}; confidence {r['confidence']:.2f}")
        else:
            lines.append(f"  {part}: {source(r)}, confidence {r['confidence']:.2f}")
    return "\n".join(lines)


def _cmd_inspect(args) -> int:
    import json

    from .learn.features import CLASSES, assign_classes
    from .core.joints import describe_legs
    from .learn.model import PostureMap

    if args.path.lower().endswith(".bvh"):
        from .io import bvh
        from .core.motion import root_index, summary

        m = bvh.read(args.path)
        jc = assign_classes(m.skeleton, root_index(m))
        info = {"file": args.path, "summary": summary(m),
                "assignment": {c: [n for n, k in zip(m.skeleton.names, jc) if k == i]
                               for i, c in enumerate(CLASSES)},
                "legs": describe_legs(m.skeleton)}
        if args.json:
            print(json.dumps(info, indent=2))
        else:
            print(f"{args.path}: {info['summary']}")
            for c, names in info["assignment"].items():
                print(f"  {c:7s} {', '.join(names) or '-'}")
            print(_legs_line(info["legs"]))
        return 0
    d = PostureMap.load(args.path).describe()
    if args.json:
        print(json.dumps(d, indent=2))
        return 0
    t = d["training"]
    print(f"{args.path}: posture map, features {d['features']}, skeleton of {d['skeleton']['joints']} joints "
          f"(root {d['skeleton']['root']}, up {d['skeleton']['up']})")
    if t:
        print(f"  trained on {t.get('clips')} clips, {t.get('frames')} frames in {t.get('train_seconds')} s")
    lib = d["library"]
    if lib:
        print(f"  motion library: {lib['frames']} frames of {lib['clips']} clips at {lib['fps']:.5g} fps"
              f"{', also played backwards' if lib['reverse'] else ''}; {lib['bytes_per_frame']:.0f} bytes per frame; "
              f"matched on {', '.join(lib['key_joints'])}")
        toe = lib.get("toe_clearance")
        if toe:
            print("  swinging toes kept at least " + " / ".join(f"{h:.3f}" for h in toe["heights"])
                  + " leg lengths above the floor at " + " / ".join(f"{v:g}" for v in toe["speeds"])
                  + " leg lengths per second (as the library's own, where above the fixed rule)")
    else:
        print("  motion library: none (retrieval falls back to interpolation)")
    p = d["params"]
    print(f"  parameters: radius {p['radius']}, neighborhood {p['neighborhood']}, learning rate "
          f"{p['learning_rate']}, epochs {p['epochs']}, seed {p['seed']}")
    print(f"  {'class':7s} {'neurons':>7s} {'dims':>4s} {'radius':>7s} {'edges':>6s} {'q.error':>8s} "
          f"{'topo.err':>8s} {'invalid':>7s}")
    for c, q in d["classes"].items():
        print(f"  {c:7s} {q['neurons']:7d} {q['dims']:4d} {q['radius']:7.3f} {q['edges']:6d} "
              f"{q.get('quantization_error', float('nan')):8.3f} {q.get('topographic_error', float('nan')):8.3f} "
              f"{q.get('invalid_neurons', float('nan')):7.3f}")
    for c, names in d["assignment"].items():
        print(f"  {c:7s} {', '.join(names) or '-'}")
    print(_legs_line(d["legs"]))
    return 0


def _legs_line(legs: list[list[str]]) -> str:
    from .core.joints import LEGS_MISSING

    return "  legs    " + ("; ".join(" > ".join(leg) for leg in legs) if legs else LEGS_MISSING)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (imports no numpy: ``posturemap --help`` answers at once)."""
    p = _Parser(prog="posturemap",
                description="Natural, real-time motion transitions between motion-capture clips "
                            "with a Uniform Posture Map.")
    p.add_argument("--version", action="version", version=f"posturemap {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    t = sub.add_parser("train", help="learn a posture map (four class UPMs) from BVH files or folders")
    t.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="BVH file or folder of BVH files (not its subfolders); one skeleton, and clips at "
                        "another frame rate than the first are resampled to it")
    t.add_argument("-o", "--output", required=True, metavar="MAP", help="map file to write (.npz)")
    t.add_argument("--radius", type=_radius, default="auto",
                   help="maximum distance from a posture to its neuron, or 'auto' (default) to derive it "
                        "from the data for each bone class (a number is used for all four: their automatic "
                        "radii differ several times over, see `posturemap inspect MAP`)")
    t.add_argument("--neighborhood", type=_hops, default=2, help="initial neighbourhood in graph hops (2)")
    t.add_argument("--epochs", type=_epochs, default=4, help="passes over the data (4)")
    t.add_argument("--learning-rate", type=_gain, default=0.5, help="initial gain in (0, 1), falls to 0 (0.5)")
    t.add_argument("--seed", type=_seed, default=0, help="random seed (0)")
    t.add_argument("--features", choices=("logmap", "euler"), default="logmap",
                   help="posture features: logmap (default, rotation vectors) or euler (the paper's angles)")
    t.add_argument("--classes", metavar="FILE.json", help='bone class overrides {"Joint": "body|global|medium|detail"}')
    t.set_defaults(func=_cmd_train)

    r = sub.add_parser("transition", help="make the transition from clip A to clip B and write a BVH or glTF",
                       formatter_class=argparse.RawDescriptionHelpFormatter,
                       epilog="methods:\n" + "\n".join(f"  {name:12s}{info.summary}" for name, info in METHOD_INFO.items()))
    r.add_argument("a", metavar="A.bvh")
    r.add_argument("b", metavar="B.bvh")
    r.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="file to write: .bvh (A's skeleton and channels), or .glb / .gltf (glTF 2.0: "
                        "metres, Y up, one animation; the clip's unit is guessed from its body height)")
    r.add_argument("--map", metavar="MAP", help="posture map (and motion library) from `posturemap train` "
                                                "(default: learn one from the frames A and B keep)")
    r.add_argument("--length", type=_positive_int, default=DEFAULT_LENGTH,
                   help=f"in-between frames ({DEFAULT_LENGTH}; a gap in one file keeps its duration with --length "
                        "equal to the frames between --a-end and --b-start: a warning says when it does not)")
    r.add_argument("--key-at", type=_positive_int, default=None,
                   help="position of the key among the in-between frames, 1..length (default length/2; "
                        "used by the key-posture methods, checked for every method)")
    r.add_argument("--alpha", type=float, default=DEFAULT_ALPHA,
                   help=f"control parameter ({DEFAULT_ALPHA}): retrieval prefers motion that continues A at 0, that arrives "
                        "in B at 1; the key-posture methods put the key near A at 0, near B at 1")
    r.add_argument("--a-end", type=_nonneg_int, default=None, help="last frame of A to keep (default: last)")
    r.add_argument("--b-start", type=_nonneg_int, default=0,
                   help="first frame of B to keep (0); B at another frame rate than A is resampled to A's, "
                        "and this counts B's own frames")
    r.add_argument("--no-align", action="store_true", help="leave B where it is (no move or turn)")
    r.add_argument("--no-foot-lock", action="store_true",
                   help="do not pin planted feet nor lift toes out of the floor and clear of it (foot-skate cleanup)")
    r.add_argument("--preview", metavar="OUT.png",
                   help="also draw a filmstrip (side and top view: A's last second, the transition, B's "
                        "first second, planted feet); needs matplotlib: pip install 'posturemap[preview]'")
    r.add_argument("--split-animations", action="store_true",
                   help="glTF only: also write A's part, the transition and B's part as three named animations")
    r.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"transition method ({DEFAULT_METHOD}: real motion retrieved from the map's library, "
                        "at every gap length; see the README)")
    r.set_defaults(func=_cmd_transition)

    i = sub.add_parser("inspect", help="describe a map file (or a BVH file's skeleton and bone classes)")
    i.add_argument("path", metavar="MAP", help="map file (.npz) or BVH file")
    i.add_argument("--json", action="store_true", help="print JSON")
    i.set_defaults(func=_cmd_inspect)

    s = sub.add_parser("resample", help="write a BVH clip at another frame rate (rotations SLERPed, translations LERPed)")
    s.add_argument("input", metavar="IN.bvh")
    # core.motion's MIN_FPS and MAX_FPS (numpy is not imported to check options)
    s.add_argument("--fps", type=_checked(float, lambda v: 0.1 <= v <= 10000.0, "a frame rate in [0.1, 10000]"),
                   required=True, help="the new frame rate (frames per second)")
    s.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="file to write: .bvh (the clip's skeleton and channels) or .glb / .gltf")
    s.set_defaults(func=_cmd_resample)

    e = sub.add_parser("bench", help="evaluate every method on a style, a content and a 120 fps hold-out "
                                     "(in-betweening accuracy, realism, speed), the main methods on four more "
                                     "splits of bandai1, and write results.md, results.json and plots; or, with "
                                     "--train and --test, on your own clips")
    e.add_argument("--quick", action="store_true", help="small run for CI (about 20 s on 2 idle cores); with --test, "
                                                        "8 seeded windows")
    e.add_argument("--data", default=None, help="data folder holding bandai1/ and cmu/ (default: $POSTUREMAP_DATA)")
    e.add_argument("--train", nargs="+", metavar="INPUT", default=None,
                   help="your own clips instead (BVH files or folders): the map and its library learn these ...")
    e.add_argument("--test", nargs="+", metavar="INPUT", default=None,
                   help="... and the gaps are cut from these (10 frames of context each side, a window every 40 "
                        "frames; one skeleton for all; the per-motion tables group them by the INPUT they came from)")
    e.add_argument("--lengths", type=_gaps, default=None, metavar="N,N,...",
                   help="with --test: the gaps in frames at the test clips' rate (default: 5, 15, 30 and 45 frames "
                        "at 30 fps, as long at that rate); the criteria take the lengths of 15, 30 and 45 at 30 fps")
    e.add_argument("--out", default="bench-results", help="output folder (default: bench-results)")
    e.add_argument("--seed", type=_seed, default=0, help="random seed (0)")
    e.set_defaults(func=_cmd_bench)

    v = sub.add_parser("serve", help="interactive transition studio in the browser")
    v.add_argument("inputs", nargs="*", metavar="INPUT",
                   help="BVH files or folders (default: the bundled sample); clips at another frame rate than "
                        "the first are resampled to it")
    v.add_argument("--map", metavar="MAP", help="posture map to use (default: learn one from the clips)")
    v.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    v.add_argument("--port", type=int, default=8000, help="port (default 8000; 0 takes a free one)")
    v.set_defaults(func=_cmd_serve)

    d = sub.add_parser("demo", help="run the whole pipeline on the bundled sample (or --data DIR)")
    d.add_argument("--out", default=None,
                   help="output folder (default: out for the sample, out-NAME for --data NAME)")
    d.add_argument("--data", default=None, help="folder of BVH files to use instead of the sample")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except UserError as e:
        sys.stderr.write(f"posturemap: error: {e}\n")
        return 2
    except FileNotFoundError as e:
        sys.stderr.write(f"posturemap: error: {e.filename}: no such file or folder\n")
        return 2
    except BrokenPipeError:  # the reader of stdout stopped early (``| head``): not an error of ours
        try:
            sys.stdout = open(os.devnull, "w")  # noqa: SIM115 (Python flushes stdout at exit)
        except OSError:
            pass
        return 141
    except OSError as e:  # permissions, a file where a folder should be, a full disk...
        sys.stderr.write(f"posturemap: error: {e.filename or ''}: {e.strerror or e}\n")
        return 2
    except MemoryError:
        sys.stderr.write("posturemap: error: memory: not enough for this input\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("posturemap: interrupted\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
