"""The ``posturemap`` command: parses arguments and calls the library (thin by design)."""

from __future__ import annotations

import argparse
import os
import sys

from . import __version__
from .errors import UserError


class _Parser(argparse.ArgumentParser):
    """Argument errors as one line on stderr and exit code 2 (no usage dump)."""

    def error(self, message):
        sys.stderr.write(f"posturemap: error: {message}\n")
        sys.exit(2)


def _cmd_bench(args) -> int:
    from . import evaluate
    return evaluate.run_cli(args)


def _cmd_serve(args) -> int:
    from .web import server
    return server.run_cli(args)


def _cmd_demo(args) -> int:
    from . import demo
    demo.run(args.out, data=args.data, log=print)
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
_positive = _checked(float, lambda v: v > 0, "a positive number or 'auto'")


def _radius(text: str):
    return "auto" if text == "auto" else _positive(text)


def _cmd_train(args) -> int:
    from .bvh import read_inputs
    from .features import load_class_overrides
    from .model import PostureMap

    _check_output(args.output)
    clips = read_inputs(args.inputs)
    classes = load_class_overrides(args.classes, clips[0][1].skeleton.names) if args.classes else None
    progress = _Progress(args.epochs)
    pm = PostureMap(args.radius, args.neighborhood, args.learning_rate, args.epochs, args.seed,
                    args.features, classes)
    try:
        pm.fit([m for _, m in clips], [p for p, _ in clips], progress=progress)
    finally:
        progress.close()
    pm.save(args.output)
    info = pm.info_
    print(f"{args.output}: {info['clips']} clips, {info['frames']} frames, "
          f"{sum(pm.neuron_counts())} neurons ("
          + ", ".join(f"{c} {q['neurons']}" for c, q in info["quality"].items())
          + f"), trained in {info['train_seconds']:.1f} s")
    return 0


def _check_output(path: str):
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UserError(path, "output folder does not exist")
    if os.path.isdir(path):
        raise UserError(path, "is a folder, expected a file name")


def _cmd_transition(args) -> int:
    from . import bvh
    from .model import PostureMap
    from .transition import KEYED, transition

    a, b = bvh.read(args.a), bvh.read(args.b)
    if not b.skeleton.same_as(a.skeleton):
        raise UserError(args.b, f"skeleton differs from {args.a} (joints, hierarchy or channels)")
    _check_output(args.output)
    model = None
    if args.map:
        model = PostureMap.load(args.map)
        model.check_skeleton(a.skeleton, args.a)
    elif args.method in KEYED:
        model = PostureMap(seed=0).fit([a, b], [args.a, args.b])
    out = transition(a, b, model, length=args.length, key_at=args.key_at, alpha=args.alpha,
                     a_end=args.a_end, b_start=args.b_start, align=not args.no_align, method=args.method,
                     foot_lock=not args.no_foot_lock)
    bvh.write(args.output, out)
    a_end = len(a) - 1 if args.a_end is None else args.a_end
    print(f"{args.output}: {len(out)} frames = A[0..{a_end}] + {args.length} {args.method} frames "
          f"+ B[{args.b_start}..{len(b) - 1}]")
    return 0


def _cmd_inspect(args) -> int:
    import json

    from .features import CLASSES, assign_classes
    from .model import PostureMap

    if args.path.lower().endswith(".bvh"):
        from . import bvh
        from .motion import root_index, summary

        m = bvh.read(args.path)
        jc = assign_classes(m.skeleton, root_index(m))
        info = {"file": args.path, "summary": summary(m),
                "assignment": {c: [n for n, k in zip(m.skeleton.names, jc) if k == i]
                               for i, c in enumerate(CLASSES)}}
        if args.json:
            print(json.dumps(info, indent=2))
        else:
            print(f"{args.path}: {info['summary']}")
            for c, names in info["assignment"].items():
                print(f"  {c:7s} {', '.join(names) or '-'}")
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
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="posturemap",
                description="Natural, real-time motion transitions between motion-capture clips "
                            "with a Uniform Posture Map.")
    p.add_argument("--version", action="version", version=f"posturemap {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    t = sub.add_parser("train", help="learn a posture map (four class UPMs) from BVH files or folders")
    t.add_argument("inputs", nargs="+", metavar="INPUT", help="BVH file or folder of BVH files")
    t.add_argument("-o", "--output", required=True, metavar="MAP", help="map file to write (.npz)")
    t.add_argument("--radius", type=_radius, default="auto",
                   help="maximum distance from a posture to its neuron, or 'auto' (default) to derive it "
                        "from the data")
    t.add_argument("--neighborhood", type=_nonneg_int, default=2, help="initial neighbourhood in graph hops (2)")
    t.add_argument("--epochs", type=_positive_int, default=4, help="passes over the data (4)")
    t.add_argument("--learning-rate", type=_gain, default=0.5, help="initial gain in (0, 1), falls to 0 (0.5)")
    t.add_argument("--seed", type=int, default=0, help="random seed (0)")
    t.add_argument("--features", choices=("logmap", "euler"), default="logmap",
                   help="posture features: logmap (default, rotation vectors) or euler (the paper's angles)")
    t.add_argument("--classes", metavar="FILE.json", help='bone class overrides {"Joint": "body|global|medium|detail"}')
    t.set_defaults(func=_cmd_train)

    from .transition import DEFAULT_METHOD, METHODS

    r = sub.add_parser("transition", help="make the transition from clip A to clip B and write a BVH")
    r.add_argument("a", metavar="A.bvh")
    r.add_argument("b", metavar="B.bvh")
    r.add_argument("-o", "--output", required=True, metavar="OUT.bvh")
    r.add_argument("--map", metavar="MAP", help="posture map from `posturemap train` (default: learn one from A and B)")
    r.add_argument("--length", type=_positive_int, default=20, help="in-between frames (20)")
    r.add_argument("--key-at", type=_positive_int, default=None,
                   help="position of the key among the in-between frames, 1..length (default length/2)")
    r.add_argument("--alpha", type=float, default=0.5, help="control parameter: 0 keys near A, 1 near B (0.5)")
    r.add_argument("--a-end", type=_nonneg_int, default=None, help="last frame of A to keep (default: last)")
    r.add_argument("--b-start", type=_nonneg_int, default=0, help="first frame of B to keep (0)")
    r.add_argument("--no-align", action="store_true", help="leave B where it is (no move or turn)")
    r.add_argument("--no-foot-lock", action="store_true", help="do not pin planted feet (foot-skate cleanup)")
    r.add_argument("--method", choices=METHODS, default=DEFAULT_METHOD,
                   help=f"transition method ({DEFAULT_METHOD})")
    r.set_defaults(func=_cmd_transition)

    i = sub.add_parser("inspect", help="describe a map file (or a BVH file's skeleton and bone classes)")
    i.add_argument("path", metavar="MAP", help="map file (.npz) or BVH file")
    i.add_argument("--json", action="store_true", help="print JSON")
    i.set_defaults(func=_cmd_inspect)

    e = sub.add_parser("bench", help="evaluate every method on a style, a content and a 120 fps hold-out "
                                     "(in-betweening accuracy, realism, speed) and write results.md, results.json "
                                     "and plots")
    e.add_argument("--quick", action="store_true", help="small run for CI (about 20 s on 2 idle cores)")
    e.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    e.add_argument("--out", default="bench-results", help="output folder (default: bench-results)")
    e.add_argument("--seed", type=int, default=0, help="random seed (0)")
    e.set_defaults(func=_cmd_bench)

    v = sub.add_parser("serve", help="interactive transition studio in the browser")
    v.add_argument("inputs", nargs="*", metavar="INPUT", help="BVH files or folders (default: the bundled sample)")
    v.add_argument("--map", metavar="MAP", help="posture map to use (default: learn one from the clips)")
    v.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    v.add_argument("--port", type=int, default=8000, help="port (default 8000; 0 takes a free one)")
    v.set_defaults(func=_cmd_serve)

    d = sub.add_parser("demo", help="run the whole pipeline on the bundled sample (or --data DIR)")
    d.add_argument("--out", default="out", help="output folder (default: out)")
    d.add_argument("--data", default=None, help="folder of BVH files to use instead of the sample")
    d.set_defaults(func=_cmd_demo)
    return p


def main(argv=None) -> int:
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
    except OSError as e:  # permissions, a file where a folder should be, a full disk...
        sys.stderr.write(f"posturemap: error: {e.filename or ''}: {e.strerror or e}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("posturemap: interrupted\n")
        return 130


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    sys.exit(main())
