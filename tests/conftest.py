"""Shared fixtures.

Real motion-capture data is read from the folder in ``POSTUREMAP_DATA`` (default:
``../shared/data`` next to the repository). Tests that need it take the ``data_dir``,
``bandai_files`` or ``cmu_file`` fixture and are skipped with a clear reason when it is absent;
``sample_clips`` (the procedural sample) is always available.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from posturemap.core import kernels
from posturemap import sample

REPO_ROOT = Path(__file__).resolve().parent.parent


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """With ``POSTUREMAP_NO_SKIP=1`` (set by .ci/run) a skipped test fails: CI must never pass
    because the data, Chromium or an extra was missing."""
    outcome = yield
    report = outcome.get_result()
    if os.environ.get("POSTUREMAP_NO_SKIP") == "1" and report.skipped and not hasattr(report, "wasxfail"):
        reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
        report.outcome = "failed"
        report.longrepr = f"skipped, but POSTUREMAP_NO_SKIP=1 forbids skips: {reason}"


@pytest.fixture(scope="session", autouse=True)
def compiled_kernels():
    """The suite runs with the compiled kernels loaded, as training, the studio and the
    benchmarks do; tests of the numpy kernels ask for them with ``kernels.numpy_backend()``
    or ``kernels.NUMPY`` (and a fresh process, for the command line)."""
    kernels.compiled()


def data_path() -> Path:
    """The real-mocap folder: ``$POSTUREMAP_DATA`` or ``<repo>/../shared/data``."""
    return Path(os.environ.get("POSTUREMAP_DATA") or REPO_ROOT.parent / "shared" / "data").resolve()


def _skip_missing(what: Path):
    pytest.skip(f"POSTUREMAP_DATA not found at {what}: real-mocap tests need ../shared/data "
                f"(or set POSTUREMAP_DATA)")


@pytest.fixture(scope="session")
def data_dir() -> Path:
    path = data_path()
    if not path.is_dir():
        _skip_missing(path)
    return path


@pytest.fixture(scope="session")
def bandai_files(data_dir) -> list[Path]:
    """Sorted Bandai-Namco dataset-1 clips (Y up, centimetres, 6 channels per joint)."""
    files = sorted((data_dir / "bandai1").glob("*.bvh"))
    if not files:
        _skip_missing(data_dir / "bandai1")
    return files


@pytest.fixture(scope="session")
def bandai_paths(bandai_files):
    """A function: Bandai clip names (without ``dataset-1_``) to ``{name: path}``; skips the
    test, naming the clips, when the data lacks some."""
    by_name = {p.stem.removeprefix("dataset-1_"): p for p in bandai_files}

    def paths(names) -> dict[str, Path]:
        missing = sorted(set(names) - set(by_name))
        if missing:
            pytest.skip(f"Bandai clips missing from {bandai_files[0].parent}: {', '.join(missing)}")
        return {n: by_name[n] for n in names}

    return paths


@pytest.fixture(scope="session")
def cmu_file(data_dir) -> Path:
    """CMU subject 1, trial 1 (120 fps, ZYX rotations, root with 6 channels)."""
    path = data_dir / "cmu" / "01_01.bvh"
    if not path.is_file():
        _skip_missing(path)
    return path


@pytest.fixture(scope="session")
def sample_clips():
    """The procedural sample clips by name (walk, run, wave); treat as read-only."""
    return sample.clips()
