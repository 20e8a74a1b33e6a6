"""Every Python example of docs/python.md runs: the DataLoader one as a script of its own,
under both start methods of its workers (fork, and spawn: macOS's and Windows' default)."""

import json
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import cylaov
from conftest import ROOT

DOC = (ROOT / "docs" / "python.md").read_text()
BLOCKS = re.findall(r"```python\n(.*?)```", DOC, re.S)
LOADER = next(i for i, b in enumerate(BLOCKS) if "DataLoader(" in b)


def test_the_page_has_its_six_examples():
    assert len(BLOCKS) == 6
    assert "cylaov.render(" in BLOCKS[0]
    assert "Scene.from_arrays(" in BLOCKS[1] and "cameras=" in BLOCKS[1]
    assert LOADER == 2
    assert "cast_rays(" in BLOCKS[3]
    assert "spawn_rays(" in BLOCKS[4]
    assert "from_table(" in BLOCKS[5] and "to_ply(" in BLOCKS[5]


@pytest.mark.parametrize("k", [k for k in range(len(BLOCKS)) if k != LOADER])
def test_example_runs(k, monkeypatch, tmp_path):
    if k == 5:
        # It writes tree.ply: in a folder of its own holding the table it reads.
        tables = tmp_path / "scenes" / "tables"
        tables.mkdir(parents=True)
        name = "tree_cyl_data.txt"
        (tables / name).write_bytes((ROOT / "scenes" / "tables" / name).read_bytes())
        monkeypatch.chdir(tmp_path)
    else:
        monkeypatch.chdir(ROOT)
    scope = {"__name__": "__main__"}
    exec(compile(BLOCKS[k], f"docs/python.md example {k}", "exec"), scope)
    if k == 0:
        assert scope["depth"].shape == (240, 320) and scope["normal"].shape == (240, 320, 3)
        assert len(scope["K"]) == 3
    if k == 1:
        assert len(scope["scene"]) == 2 and len(scope["scene"].cameras) == 2
        ids = scope["ids"]
        assert ids.shape == (24, 32) and ids.dtype.name == "uint32"
        assert set(ids.ravel().tolist()) == {0, 7, 9}
    if k == 3:
        assert scope["rng"].shape == (16, 720)
        assert 100 < len(scope["cloud"]) < 16 * 720, len(scope["cloud"])
    if k == 4:
        # A mirror bounce leaves outward: it never finds the cylinder it bounced off.
        hit, second = scope["hit"], scope["second"]
        assert len(hit["t_hit"]) > 20
        assert not np.any(second["shape_id"] == hit["shape_id"])
    if k == 5:
        assert len(scope["scene"]) == 33
        hits = int((scope["out"]["shape_id"] != 0).sum())
        assert scope["points"] == hits > 1000
        assert (tmp_path / "tree.ply").stat().st_size > 36 * hits
        assert set(scope["out"]["label"].ravel().tolist()) == {0, 1, 2, 3}


def test_the_stub_example_of_from_arrays_runs():
    stub = (ROOT / "python" / "cylaov" / "__init__.pyi").read_text()
    m = re.search(r"def from_arrays\(.*?Example::\n\n(.*?)\n\s*\"\"\"", stub, re.S)
    scope = {"cylaov": cylaov}
    exec(compile(textwrap.dedent(m.group(1)), "from_arrays example", "exec"), scope)
    assert [c["width"] for c in scope["scene"].cameras] == [64, 32]
    assert scope["depth"].shape == (24, 32) and (scope["depth"] > 0).any()


def _torch():
    """Whether torch imports; without it the test fails under scripts/test and CI (the venv
    of scripts/setup-venv has it) and skips elsewhere."""
    r = subprocess.run([sys.executable, "-c", "import torch"], capture_output=True, text=True)
    if r.returncode != 0:
        if os.environ.get("CYLAOV_REQUIRE_VENV") == "1" or os.environ.get("CI") == "true":
            pytest.fail(f"torch is not installed in the test venv (scripts/setup-venv): {r.stderr}")
        pytest.skip("torch is not installed (scripts/setup-venv installs it)")


# Runs the page's block as the main script of a new Python, as a user runs it: spawned
# workers import that file again (as `__mp_main__`), which the block's `__main__` guard
# allows; forked ones do not. Prints what the block's loop left.
RUN_AS_SCRIPT = """
import json, runpy, sys
g = runpy.run_path(sys.argv[1], run_name="__main__")
print(json.dumps({"depth": list(g["depth"].shape), "normal": list(g["normal"].shape),
                  "dtype": str(g["depth"].dtype)}))
"""


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_the_dataloader_example_runs_with_forked_and_spawned_workers(method, tmp_path):
    _torch()
    code = BLOCKS[LOADER]
    call = "num_workers=2)"
    assert code.count(call) == 1, "the example's DataLoader call changed: update this test"
    script = tmp_path / "example.py"
    script.write_text(code.replace(call, f"num_workers=2, multiprocessing_context={method!r})"))
    r = subprocess.run([sys.executable, "-c", RUN_AS_SCRIPT, str(script)], capture_output=True,
                       text=True, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    got = json.loads(r.stdout.splitlines()[-1])
    assert got == {"depth": [8, 120, 160], "normal": [8, 120, 160, 3], "dtype": "torch.float32"}
