"""Shared fixtures of the Python package's tests: the repository's scenes, the command
line binary (the same build's), and a helper that renders with it."""

import os
import pathlib
import subprocess

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "scenes").glob("*.json")) + sorted((ROOT / "scenes" / "stress").glob("*.json"))
ALL_AOVS = ("distance", "depth", "normal", "position", "shape_id", "part", "normal_camera")


def _binary():
    env = os.environ.get("CYLAOV_BIN")
    path = pathlib.Path(env) if env else ROOT / "target" / "release" / "cylaov"
    return path if path.is_file() else None


@pytest.fixture(scope="session")
def cli():
    """The `cylaov` binary (`$CYLAOV_BIN`, else target/release/cylaov, which `cargo test
    --release` builds); missing, the test fails under scripts/test and skips elsewhere."""
    path = _binary()
    if path is None:
        if os.environ.get("CYLAOV_REQUIRE_VENV") == "1":
            pytest.fail("no cylaov binary: run cargo build --release or set CYLAOV_BIN")
        pytest.skip("no cylaov binary (cargo build --release)")

    def run(*args, check=True):
        r = subprocess.run([str(path), *map(str, args)], capture_output=True, text=True)
        if check and r.returncode != 0:
            raise AssertionError(f"cylaov {' '.join(map(str, args))}: exit {r.returncode}\n{r.stderr}")
        return r

    return run


def need(module):
    """Import a test-venv module (a reader the tests check files with); missing, the test
    fails under scripts/test or CI and skips elsewhere."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        if os.environ.get("CYLAOV_REQUIRE_VENV") == "1" or os.environ.get("CI") == "true":
            pytest.fail(f"{module} is not installed in the test venv (scripts/setup-venv): {e}")
        pytest.skip(f"{module} is not installed (scripts/setup-venv installs it)")


def exr_channels(path):
    """Every channel of an EXR as a flat numpy array, read by the OpenEXR package (not by
    cylaov), keyed by channel name."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {name: ch.pixels for name, ch in f.channels().items()}
