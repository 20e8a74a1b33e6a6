"""Every Python example of docs/python.md runs; the DataLoader one needs torch (not
installed by default: its wheels are gigabytes), so it runs only where torch imports."""

import importlib.util
import os
import re

import pytest

from conftest import ROOT

DOC = (ROOT / "docs" / "python.md").read_text()
BLOCKS = re.findall(r"```python\n(.*?)```", DOC, re.S)


def test_the_page_has_its_three_examples():
    assert len(BLOCKS) == 3
    assert "cylaov.render(" in BLOCKS[0]
    assert "DataLoader(" in BLOCKS[1]
    assert "cast_rays(" in BLOCKS[2]


@pytest.mark.parametrize("k", range(len(BLOCKS)))
def test_example_runs(k, monkeypatch):
    code = BLOCKS[k]
    if "import torch" in code and importlib.util.find_spec("torch") is None:
        pytest.skip("torch is not installed")
    monkeypatch.chdir(ROOT)
    scope = {}
    exec(compile(code, f"docs/python.md example {k}", "exec"), scope)
    if k == 0:
        assert scope["depth"].shape == (240, 320) and scope["normal"].shape == (240, 320, 3)
        assert len(scope["K"]) == 3
    if k == 2:
        assert scope["rng"].shape == (16, 720)
        assert 100 < len(scope["cloud"]) < 16 * 720, len(scope["cloud"])
