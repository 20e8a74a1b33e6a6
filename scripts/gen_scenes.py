#!/usr/bin/env python3
"""Regenerate the procedurally made scenes: scenes/cluster.json, scenes/grazing_fence.json and
scenes/stress/grazing.json.

Deterministic: a fixed seed and Python's Mersenne Twister (`random.Random`, whose stream is
stable across Python versions for `random()`); coordinates rounded to 3 decimals so the
files read well and both renderers parse the same decimals.
Usage: python3 scripts/gen_scenes.py   (from the repository root)
"""

import json
import math
import random

ALL_AOVS = ["distance", "depth", "normal", "position", "shape_id"]


def r3(x):
    return round(x, 3)


def write(path, scene):
    cam = json.dumps(scene["camera"])
    cyls = ",\n    ".join(json.dumps(c) for c in scene["cylinders"])
    text = (
        '{\n  "camera": ' + cam + ',\n  "cylinders": [\n    ' + cyls + "\n  ],\n"
        '  "aovs": ' + json.dumps(scene["aovs"]) + "\n}\n"
    )
    with open(path, "w") as f:
        f.write(text)


def cluster():
    """120 random cylinders in a 4x4x4 box: dense, overlapping, every orientation."""
    rng = random.Random(20240604)
    cyls = []
    for i in range(120):
        p0 = [rng.uniform(-2, 2) for _ in range(3)]
        theta = math.acos(rng.uniform(-1, 1))
        phi = rng.uniform(0, 2 * math.pi)
        length = rng.uniform(0.3, 1.6)
        d = [math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)]
        p1 = [p0[k] + length * d[k] for k in range(3)]
        cyls.append(
            {
                "p0": [r3(x) for x in p0],
                "p1": [r3(x) for x in p1],
                "radius": r3(rng.uniform(0.04, 0.25)),
                "caps": rng.random() < 0.7,
            }
        )
    return {
        "camera": {
            "origin": [7, -8, 5], "target": [0, 0, 0], "up": [0, 0, 1],
            "fov_deg": 38, "width": 320, "height": 240,
        },
        "cylinders": cyls,
        "aovs": ALL_AOVS,
    }


def grazing():
    """A fence of 40 thin rods seen almost edge-on: mostly silhouettes and grazing hits.

    In scenes/stress/: the rods are so thin (radius 0.03) that the most grazing hits are
    ill-conditioned (kappa ~ 100) and Mitsuba's float32 ray transform is the inaccurate side
    (0.15 deg of normal), so it is checked against the oracle, not against Mitsuba.
    """
    cyls = []
    for i in range(40):
        y = -4 + 0.2 * i
        x = 0.05 * math.sin(1.7 * i)
        cyls.append(
            {
                "p0": [r3(x - 3), r3(y), r3(0.02 * i)],
                "p1": [r3(x + 3), r3(y + 0.1), r3(0.02 * i + 0.3)],
                "radius": r3(0.03 + 0.002 * (i % 7)),
                "caps": i % 3 != 0,
            }
        )
    return {
        "camera": {
            "origin": [0.4, -12, 0.9], "target": [0, 0, 0.4], "up": [0, 0, 1],
            "fov_deg": 30, "width": 320, "height": 200,
        },
        "cylinders": cyls,
        "aovs": ALL_AOVS,
    }


def grazing_fence():
    """The Mitsuba-checked version of grazing(): 16 thicker rods (radius 0.1 to 0.13) seen
    almost edge-on from 10 units, still mostly silhouettes and grazing hits, but Mitsuba's
    float32 error stays within the reference tests' normal bound."""
    cyls = []
    for i in range(16):
        y = -4 + 0.5 * i
        x = 0.05 * math.sin(1.7 * i)
        cyls.append(
            {
                "p0": [r3(x - 3), r3(y), r3(0.05 * i)],
                "p1": [r3(x + 3), r3(y + 0.1), r3(0.05 * i + 0.3)],
                "radius": r3(0.1 + 0.005 * (i % 7)),
                "caps": i % 3 != 0,
            }
        )
    return {
        "camera": {
            "origin": [0.4, -10, 0.9], "target": [0, 0, 0.4], "up": [0, 0, 1],
            "fov_deg": 34, "width": 320, "height": 200,
        },
        "cylinders": cyls,
        "aovs": ALL_AOVS,
    }


if __name__ == "__main__":
    write("scenes/cluster.json", cluster())
    write("scenes/grazing_fence.json", grazing_fence())
    write("scenes/stress/grazing.json", grazing())
