"""The paper's claim, measured: on non-convex data a SOM leaves neurons where no sample is; the UPM does not.

Section 2 of the paper: "when the sample space has a non-convex [shape], the part of the
output neurons are sometimes formed out of the valid space" — and the UPM's insertion rule
prevents it. Three data sets (all seeded):

- ``ring``: uniform samples of the annulus 1 <= |x| <= 2 (2-D).
- ``C shape``: the same annulus without the sector |angle| < 60 degrees (2-D).
- ``bandai UpperArm_L swing``: the direction of the left upper arm over every clip of
  bandai1 (31,914 frames): the swing part of the joint's rotation relative to its mean
  (``features`` logmap reference), as a rotation vector perpendicular to the bone: the two
  DOF that place the arm (the paper's Fig. 2), in radians. Skipped without the data.

Maps: the UPM (``radius`` R, other parameters at their defaults: neighbourhood 2, gain 0.5,
4 epochs) and two classic fixed-grid SOMs (MiniSom, Gaussian neighbourhood, its default
asymptotic decay, weights initialised on random samples) with a grid of (almost) the same
neuron count as the UPM: sigma 1 (MiniSom's default) and sigma = grid side / 4 (a well-
ordered map), learning rate 0.5, ``--som-iterations`` (5) x n random presentations, more
than the UPM's 4 x n.

Reported per data set and map: neurons, "invalid" neurons (farther than R from every
sample: postures the data never shows), their fraction, the largest neuron-to-data
distance, the quantisation error (mean sample-to-nearest-neuron distance), and coverage:
the share of samples farther than R from every neuron and the largest such distance; and
"edges over a gap": map edges (SOM grid links; UPM neighbour graph) whose midpoint is farther
than R from every sample, i.e. a path along the map that would pass through unreal postures.

Usage::

    python bench/nonconvex.py [--out DIR] [--data DIR] [--json PATH] [--quick] [--no-plot]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

from posturemap.learn.upm import UniformPostureMap


def default_data_dir() -> Path:
    """``$POSTUREMAP_DATA`` or ``../shared/data`` next to the repository."""
    env = os.environ.get("POSTUREMAP_DATA")
    return Path(env) if env else ROOT.parent / "shared" / "data"


# -- data sets -------------------------------------------------------------------------------
def ring(n: int = 3000, seed: int = 0, inner: float = 1.0, outer: float = 2.0) -> np.ndarray:
    """Uniform samples of the annulus ``inner <= |x| <= outer``, shape (n, 2)."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(inner ** 2, outer ** 2, n))
    t = rng.uniform(0.0, 2.0 * np.pi, n)
    return np.c_[r * np.cos(t), r * np.sin(t)]


def c_shape(n: int = 3000, seed: int = 0) -> np.ndarray:
    """The annulus 1 <= |x| <= 2 without the sector |angle| < 60 degrees, shape (n, 2)."""
    rng = np.random.default_rng(seed)
    r = np.sqrt(rng.uniform(1.0, 4.0, n))
    t = rng.uniform(np.radians(60.0), np.radians(300.0), n)
    return np.c_[r * np.cos(t), r * np.sin(t)]


def arm_swing(data_dir: Path, joint: str = "UpperArm_L") -> np.ndarray | None:
    """Swing rotation vectors (2-D, radians) of ``joint`` over all bandai1 clips, or None."""
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        return None
    from posturemap.io import bvh
    from posturemap.learn import features
    from posturemap.core import quat

    motions = [bvh.read(f) for f in files]
    space = features.fit_space(motions, "logmap")
    sk = motions[0].skeleton
    j = sk.index(joint)
    k = int(np.flatnonzero(space.joints == j)[0])
    child = sk.children(j)[0]
    axis = sk.offsets[child] / np.linalg.norm(sk.offsets[child])  # the bone, in the joint's frame
    q = np.concatenate([m.rotations[:, j] for m in motions])
    swing, _ = quat.swing_twist(quat.mul(quat.inv(space.reference[k]), q), axis)
    s = quat.log(swing)  # perpendicular to the bone
    helper = np.eye(3)[np.argmin(np.abs(axis))]
    b1 = np.cross(axis, helper)
    b1 /= np.linalg.norm(b1)
    b2 = np.cross(axis, b1)
    return np.c_[s @ b1, s @ b2]


# -- maps ------------------------------------------------------------------------------------
def grid_shape(n: int) -> tuple[int, int]:
    """Rows and columns of the most square grid with about ``n`` neurons."""
    rows = max(1, round(np.sqrt(n)))
    cols = max(1, round(n / rows))
    return rows, cols


def fit_som(X: np.ndarray, rows: int, cols: int, sigma: float, iterations: int, seed: int,
            learning_rate: float = 0.5) -> tuple[np.ndarray, float]:
    """MiniSom weights (rows*cols, D) in grid order, and the training seconds."""
    from minisom import MiniSom

    som = MiniSom(rows, cols, X.shape[1], sigma=sigma, learning_rate=learning_rate, random_seed=seed)
    som.random_weights_init(X)
    t0 = time.perf_counter()
    som.train_random(X, iterations)
    return som.get_weights().reshape(rows * cols, X.shape[1]).copy(), time.perf_counter() - t0


def grid_edges(rows: int, cols: int) -> np.ndarray:
    idx = np.arange(rows * cols).reshape(rows, cols)
    return np.concatenate([np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()],
                           np.c_[idx[:-1].ravel(), idx[1:].ravel()]])


def evaluate(W: np.ndarray, X: np.ndarray, radius: float, tree: cKDTree, edges: np.ndarray) -> dict:
    """Invalid neurons (farther than ``radius`` from every sample), quantisation error, coverage,
    and map edges whose midpoint is farther than ``radius`` from every sample."""
    to_data, _ = tree.query(W)
    mid_dist, _ = tree.query(0.5 * (W[edges[:, 0]] + W[edges[:, 1]])) if len(edges) else (np.zeros(0), None)
    to_neuron, _ = cKDTree(W).query(X)
    invalid = to_data > radius * (1 + 1e-9)
    return {"neurons": len(W), "invalid": int(invalid.sum()),
            "invalid_fraction": float(invalid.mean()), "max_neuron_to_data": float(to_data.max()),
            "quantization_error": float(to_neuron.mean()), "max_sample_to_neuron": float(to_neuron.max()),
            "uncovered_fraction": float(np.mean(to_neuron > radius * (1 + 1e-9))),
            "edges": len(edges), "edges_over_gap": int(np.sum(mid_dist > radius * (1 + 1e-9))),
            "invalid_mask": invalid}


def compare(name: str, X: np.ndarray, radius: float | str, seed: int, som_iterations: int) -> dict:
    """UPM and two SOMs on one data set."""
    tree = cKDTree(X)
    t0 = time.perf_counter()
    upm = UniformPostureMap(radius=radius, seed=seed).fit(X)
    upm_seconds = time.perf_counter() - t0
    r = upm.radius_
    rows, cols = grid_shape(upm.n_neurons)
    out = {"name": name, "samples": len(X), "radius": float(r), "grid": [rows, cols], "maps": {}}
    res = evaluate(upm.weights_, X, r, tree, upm.edges_)
    res.update(seconds=upm_seconds, weights=upm.weights_, edge_list=upm.edges_,
               iterations=int(upm.epochs * len(X)))
    out["maps"]["UPM"] = res
    for label, sigma in (("SOM sigma=1", 1.0), ("SOM sigma=side/4", max(rows, cols) / 4.0)):
        W, seconds = fit_som(X, rows, cols, sigma, som_iterations * len(X), seed)
        edges = grid_edges(rows, cols)
        res = evaluate(W, X, r, tree, edges)
        res.update(seconds=seconds, weights=W, edge_list=edges, sigma=sigma,
                   iterations=int(som_iterations * len(X)))
        out["maps"][label] = res
    return out


# -- output ----------------------------------------------------------------------------------
def plot(results: list[dict], data: dict[str, np.ndarray], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    labels = list(results[0]["maps"])
    labels = labels[1:] + labels[:1]  # SOMs first, UPM last
    fig, axes = plt.subplots(len(results), len(labels), figsize=(4.2 * len(labels), 4.2 * len(results)),
                             squeeze=False)
    for row, res in zip(axes, results):
        X = data[res["name"]]
        if len(X) > 8000:  # a seeded subset of the samples keeps the PNG small
            X = X[np.random.default_rng(0).choice(len(X), 8000, replace=False)]
        for ax, label in zip(row, labels):
            m = res["maps"][label]
            W, bad = m["weights"], m["invalid_mask"]
            ax.scatter(X[:, 0], X[:, 1], s=1.5, c="0.78", lw=0, rasterized=True)
            ax.add_collection(LineCollection(W[m["edge_list"]], colors="tab:blue", linewidths=0.4, alpha=0.6))
            ax.scatter(W[~bad, 0], W[~bad, 1], s=7, c="tab:blue", lw=0, zorder=3)
            ax.scatter(W[bad, 0], W[bad, 1], s=22, c="tab:red", marker="x", lw=1.2, zorder=4)
            title = label.replace("side/4", f"{m['sigma']:g}") if "sigma" in m else label
            ax.set_title(f"{res['name']}: {title}\n{m['neurons']} neurons, {m['invalid']} invalid "
                         f"(> R={res['radius']:.3g} from data)", fontsize=9)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def markdown(report: dict) -> str:
    lines = [("| data set | samples | R | map | neurons | invalid | invalid % | max neuron-data | quant. error "
             "| samples > R from map % | max sample-neuron | edges over a gap |"),
             "|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for res in report["datasets"]:
        for label, m in res["maps"].items():
            if "sigma" in m:
                label = f"{label.split(' sigma')[0]} {res['grid'][0]}x{res['grid'][1]}, sigma {m['sigma']:g}"
            lines.append(f"| {res['name']} | {res['samples']} | {res['radius']:.3g} | {label} | {m['neurons']} | "
                         f"{m['invalid']} | {100 * m['invalid_fraction']:.1f} | {m['max_neuron_to_data']:.3f} | "
                         f"{m['quantization_error']:.4f} | {100 * m['uncovered_fraction']:.2f} | "
                         f"{m['max_sample_to_neuron']:.3f} | {m['edges_over_gap']} of {m['edges']} |")
    return "\n".join(lines)


def _jsonable(report: dict) -> dict:
    drop = ("weights", "edge_list", "invalid_mask")
    return {**report, "datasets": [{**d, "maps": {k: {a: b for a, b in m.items() if a not in drop}
                                                   for k, m in d["maps"].items()}}
                                   for d in report["datasets"]]}


def run(out: str | os.PathLike | None = "docs", data: str | os.PathLike | None = None, n: int = 3000,
        radius: float = 0.25, arm_radius: float | str = 0.15, seed: int = 0, som_iterations: int = 5,
        quick: bool = False, make_plot: bool = True) -> dict:
    """Run the comparison; returns a JSON-ready dict (plot at ``out/nonconvex.png``)."""
    if quick:
        n, som_iterations = 1000, 3
    data_dir = Path(data) if data else default_data_dir()
    sets = {"ring": (ring(n, seed), radius), "C shape": (c_shape(n, seed), radius)}
    arm = arm_swing(data_dir)
    if arm is not None:
        if quick:
            arm = arm[np.random.default_rng(seed).choice(len(arm), 5000, replace=False)]
        sets["bandai UpperArm_L swing"] = (arm, arm_radius)
    results = [compare(name, X, r, seed, som_iterations) for name, (X, r) in sets.items()]
    report = {"date": time.strftime("%Y-%m-%d"), "seed": seed, "som_iterations_per_sample": som_iterations,
              "upm_epochs": 4, "datasets": results}
    if make_plot and out is not None:
        png = Path(out) / "nonconvex.png"
        plot(results, {name: X for name, (X, _) in sets.items()}, png)
        report["plot"] = str(png)
    return _jsonable(report)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default=str(ROOT / "docs"), help="folder for nonconvex.png (default: docs/)")
    p.add_argument("--data", default=None, help="data folder (default: $POSTUREMAP_DATA or ../shared/data)")
    p.add_argument("--json", default=None, metavar="PATH", help="also write the results as JSON")
    p.add_argument("--samples", type=int, default=3000, help="samples of each synthetic set (3000)")
    p.add_argument("--radius", type=float, default=0.25, help="UPM radius on the synthetic sets (0.25)")
    p.add_argument("--arm-radius", default="0.15", help="UPM radius on the arm swing, radians, or auto (0.15)")
    p.add_argument("--som-iterations", type=int, default=5, help="SOM presentations per sample (5)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--quick", action="store_true", help="smaller sets, fewer SOM iterations")
    p.add_argument("--no-plot", action="store_true")
    args = p.parse_args(argv)
    arm_radius = args.arm_radius if args.arm_radius == "auto" else float(args.arm_radius)
    report = run(args.out, args.data, args.samples, args.radius, arm_radius, args.seed, args.som_iterations,
                 args.quick, not args.no_plot)
    print(markdown(report))
    if "plot" in report:
        print(f"\nplot: {report['plot']}")
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
