"""cylaov: cylinder scenes to per-pixel AOVs as numpy arrays, with no files.

The same Rust library as the ``cylaov`` command: ``render`` returns, bit for bit, the
samples of the EXR that ``cylaov render`` writes.

A first render::

    import cylaov
    scene = cylaov.Scene.load("scenes/cluster.json")
    out = cylaov.render(scene, aovs=("depth", "normal", "shape_id"))
    out["depth"]      # (H, W) float32, camera-space z; 0 where the ray misses
    out["normal"]     # (H, W, 3) float32, world-space unit outward normal
    out["mask"]       # (H, W) bool, True where a cylinder was hit

Functions: ``render``, ``camera_info``, ``cast_rays``, ``spawn_rays``, ``camera_rays``, ``scan``,
``generate``, ``read``, ``compare``, ``write_shards``, ``shard_count``, ``to_ply``; classes ``Scene``, ``Dataset``; errors ``SceneError`` (a
``ValueError``) and ``OSError`` subclasses for files. ``help(cylaov.render)`` and the others
say more; the package's documentation page is ``docs/python.md`` in the repository.
"""

import functools as _functools
import inspect as _inspect
import json as _json
import math as _math
import numbers as _numbers
import operator as _operator
import os as _os
import re as _re
import sys as _sys
import tempfile as _tempfile
import threading as _threading
import weakref as _weakref

import numpy as _np

from . import _cylaov
from ._cylaov import (
    InternalError,
    Scene,
    SceneError,
    __version__,
    camera_info,
    camera_rays,
    compare,
    read,
    shard_count,
)

__all__ = [
    "Scene",
    "SceneError",
    "InternalError",
    "Dataset",
    "render",
    "camera_info",
    "cast_rays",
    "spawn_rays",
    "camera_rays",
    "scan",
    "generate",
    "read",
    "compare",
    "write_shards",
    "shard_count",
    "to_ply",
    "__version__",
]


def _shorten(text):
    """``text`` with every run of more than 40 letters, digits or dots cut to its first 20
    and last 8 characters with the count between, as the Rust half shortens what its
    messages echo: a megabyte of value does not flood the terminal."""
    return _re.sub(r"[A-Za-z0-9.]{41,}",
                   lambda m: f"{m[0][:20]}…({len(m[0]) - 28} more)…{m[0][-8:]}", text)


def _described(value):
    """A value for a message: its type and its shortened repr, ``int 1``, ``str 'x'``."""
    return f"{type(value).__name__} {_shorten(repr(value))}"


def _is_real(value):
    """Whether ``value`` is a real number (``int``, ``float``, a numpy real), as a ``float``
    argument takes it; not a string, a complex number or a bool standing for one."""
    return isinstance(value, _numbers.Real) and not isinstance(value, (bool, _np.bool_))


# What an argument whose default is of this type must be, and how a message says it.
_KINDS = {
    str: (lambda v: isinstance(v, str), "a str"),
    bool: (lambda v: isinstance(v, (bool, _np.bool_)), "a bool"),
    float: (_is_real, "a real number"),
}


def _checked(*skip):
    """Decorate a function so that each argument whose default is a ``str``, ``bool`` or
    ``float`` (but those named in ``skip``, which take more) must be one, else
    ``TypeError`` naming the argument and the value (``force: must be a bool, got int
    1``): pyo3's own refusal names neither (``'int' object is not an instance of
    'bool'``). Read from the signature, so each such argument of a wrapped function, and
    of any added later, is checked without a line of its own."""

    def wrap(f):
        params = list(_inspect.signature(f).parameters.values())
        kinds = {p.name: _KINDS[type(p.default)] for p in params
                 if type(p.default) in _KINDS and p.name not in skip}
        names = [p.name for p in params]

        @_functools.wraps(f)
        def call(*args, **kwargs):
            for name, value in zip(names, args):
                _check_kind(kinds, name, value)
            for name, value in kwargs.items():
                _check_kind(kinds, name, value)
            return f(*args, **kwargs)

        if getattr(f, "__text_signature__", None):
            call.__text_signature__ = f.__text_signature__
        return call

    return wrap


def _check_kind(kinds, name, value):
    kind = kinds.get(name)
    if kind is not None and not kind[0](value):
        raise TypeError(f"{name}: must be {kind[1]}, got {_described(value)}")


# The compiled functions with such arguments (the others take numbers, checked there).
render = _checked()(_cylaov.render)


def _real_array(x, name):
    """``x`` as a float64 array; complex values (whose imaginary part the conversion would
    drop with a mere warning) and what numpy cannot convert raise ``ValueError`` naming
    ``name``, as ``Scene.from_arrays`` refuses them."""
    try:
        a = _np.asarray(x)
        if a.dtype.kind == "c":
            raise ValueError(f"{name}: complex values; rays take real numbers")
        return _np.asarray(a, dtype=_np.float64)
    except (TypeError, ValueError) as e:
        if str(e).startswith(f"{name}: "):
            raise
        raise ValueError(f"{name}: not an array of real numbers: {_shorten(str(e))}") from None


@_checked("t_min", "t_max")
def cast_rays(scene, origins, directions, t_min=0.0, t_max=float("inf"),
              aovs=("t_hit", "normal", "shape_id", "part"), precision="f64",
              formula="stable", threads=None):
    """Cast any rays against the scene's cylinders, in f64: the nearest hit of each.

    ``origins`` and ``directions`` are arrays of shape ``(..., 3)`` (converted to float64;
    ``origins`` broadcasts, so one ``(3,)`` origin serves every ray). Directions need not
    be unit vectors: ``t_hit`` is in units of each direction's length, as in Open3D's
    ``RaycastingScene.cast_rays``, so the hit is at ``origin + t_hit * direction``.
    ``t_min``/``t_max`` (scalars or arrays broadcasting to ``(...)``) bound ``t``.

    Returns a dict of the requested ``aovs``: ``t_hit`` ``(...)`` float64 (``inf`` on a
    miss), ``normal`` ``(..., 3)`` float64 (world-space unit outward normal, 0 on a miss),
    ``shape_id`` and ``part`` ``(...)`` uint32 (0 on a miss, as in the EXR: part 1 side from
    outside, 2 side from inside, 3 bottom cap, 4 top cap), ``position`` ``(..., 3)`` float64
    (the hit moved along its normal onto the surface it hit, pbrt-v4's reprojection: within
    the error of ``t_hit`` of ``origin + t_hit * direction``), ``position_error``
    ``(..., 3)`` float64 (per world axis, a conservative bound on how far ``position`` lies
    off that surface; 0 on a miss). ``spawn_rays`` uses the last two to continue from a hit.

    Rays sharing an origin share one prepared scene (as a render's pixel rays do); each
    distinct origin prepares it anew, so group rays by origin (a LiDAR scan: one origin).
    With ``camera_rays``' rays and the camera's ``near_clip``/``far_clip`` as ``t_min``/
    ``t_max``, ``float32(t_hit * |d|)`` is the EXR's ``distance``, bit for bit.

    Bad rays (zero or non-finite direction, ``t_min < 0``, ``t_max < t_min``) raise
    ``ValueError`` naming the ray's flat index; any finite non-zero direction is one, however
    long or short (``[1e300, 0, 0]``). Complex values are refused, not cut to their real
    part.
    """
    d = _real_array(directions, "directions")
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValueError(f"directions: shape must be (..., 3), got {d.shape}")
    shape = d.shape[:-1]
    o = _real_array(origins, "origins")
    lo = _real_array(t_min, "t_min")
    hi = _real_array(t_max, "t_max")
    try:
        wide = (_np.broadcast_to(o, d.shape), _np.broadcast_to(lo, shape),
                _np.broadcast_to(hi, shape))
    except ValueError as e:
        raise ValueError(f"origins, t_min, t_max must broadcast to {shape}: {e}") from None
    aovs = _names(aovs, "aovs: a ray output name or a sequence of them")
    # One origin or one bound for every ray goes as it is: a copy a ray would be memory
    # and time (8 million rays: 192 MB) to say the same.
    flat = lambda a, k: _np.ascontiguousarray(a.reshape((-1,) + k))
    one = (o.shape[-1:] == (3,) and o.size == 3, lo.size == 1, hi.size == 1)
    o, lo, hi = (flat(x if once else w, k)
                 for x, w, k, once in zip((o, lo, hi), wide, ((3,), (), ()), one))
    out = _cylaov._cast_rays(scene, o, flat(d, (3,)), lo, hi, list(aovs), precision, formula,
                             threads)
    return {k: v.reshape(shape + v.shape[1:]) for k, v in out.items()}


@_checked()
def scan(scene, sensor, pose=None, trajectory=None, returns=1, range_noise=0.0,
         dropout=0.0, seed=0, threads=None):
    """One rotation of a simulated LiDAR: the points as a dict of numpy arrays.

    The same points as ``cylaov scan`` (docs/scan.md), and the same arrays as the ``.npz``
    it writes: ``x``, ``y``, ``z``, ``range``, ``range_exact``, ``azimuth``, ``elevation``,
    ``time`` (float64), ``ring``, ``return_index``, ``num_returns``, ``shape_id``, ``part``,
    ``label`` (uint32), each ``(N,)``, and ``normal`` ``(N, 3)`` float32; points in world
    coordinates, ordered by azimuth step, then ring, then return.

    ``scene``: a ``Scene`` or a scene file's path. ``sensor``: a preset (``"vlp16"``,
    ``"hdl32"``, ``"os1-64"``), a sensor JSON file's path, or that JSON as a dict.
    ``pose``: ``(x, y, z)`` or ``(x, y, z, yaw, pitch, roll)`` in degrees (default the
    origin). ``trajectory``: a CSV file's path (``time,x,y,z,yaw,pitch,roll``) or an
    ``(M, 7)`` array of those rows (errors name the row, ``trajectory[1]``), instead of
    ``pose`` (giving both is refused). ``returns``: most returns per beam (1 to 15). ``range_noise``
    (sigma, along the beam), ``dropout`` (probability) and ``seed``: the same seed gives
    the same points on any number of ``threads``.

    Example::

        pts = cylaov.scan("scenes/cluster.json", "vlp16", pose=(0, 0, 1.8), returns=3)
        xyz = np.stack([pts["x"], pts["y"], pts["z"]], axis=1)
    """
    if not isinstance(scene, Scene):
        scene = Scene.load(_os.fspath(scene))
    if isinstance(sensor, dict):
        sensor = _json_text(sensor, "sensor")
    elif isinstance(sensor, (str, _os.PathLike)) and _os.path.isfile(sensor):
        with open(sensor, encoding="utf-8") as f:
            sensor = f.read()
    elif not isinstance(sensor, str):
        raise TypeError(f"sensor: a preset name, a JSON file's path or a dict, got {type(sensor).__name__}")
    if pose is not None and trajectory is not None:
        raise ValueError("pose: give pose or trajectory, not both (the trajectory's rows are "
                         "the poses)")
    csv = None
    rows = None
    if trajectory is not None:
        if isinstance(trajectory, (str, _os.PathLike)):
            with open(trajectory, encoding="utf-8") as f:
                csv = f.read()
        else:
            rows = _real_array(trajectory, "trajectory")
            if rows.ndim != 2 or rows.shape[1] != 7:
                raise ValueError(f"trajectory: shape must be (M, 7), got {rows.shape}")
            bad = _np.argwhere(~_np.isfinite(rows))
            if len(bad):
                i, j = bad[0]
                raise ValueError(f"trajectory[{i}, {j}]: must be a finite number, got "
                                 f"{float(rows[i, j])!r}")
            csv = "time,x,y,z,yaw,pitch,roll\n" + "".join(
                ",".join(repr(float(v)) for v in r) + "\n" for r in rows)
    pose = _reals((0.0, 0.0, 0.0) if pose is None else pose, "pose",
                  "(x, y, z) or (x, y, z, yaw, pitch, roll)")
    try:
        return _cylaov._scan(scene, sensor, pose, csv, returns, float(range_noise),
                             float(dropout), seed, threads)
    except ValueError as e:
        # The CSV made of the rows names its lines (a header, then 1-based): name the row.
        line = _re.match(r"trajectory line (\d+): (.*)", str(e), _re.S)
        if rows is None or line is None:
            raise
        why = line.group(2).replace("previous line", "previous row")
        raise ValueError(f"trajectory[{int(line.group(1)) - 2}]: {why}") from None


def _reals(values, name, what):
    """A sequence of real numbers as floats; else ``TypeError`` naming ``name`` (or the
    item, ``pose[1]``) and the value."""
    if isinstance(values, (str, bytes)) or not hasattr(values, "__iter__"):
        raise TypeError(f"{name}: {what} in numbers, got {_described(values)}")
    out = []
    for i, v in enumerate(values):
        if not _is_real(v):
            raise TypeError(f"{name}[{i}]: must be a real number, got {_described(v)}")
        out.append(float(v))
    return out


def spawn_rays(hits, directions):
    """Origins for rays continuing from the hits of ``cast_rays`` in ``directions``.

    ``hits`` is the dict ``cast_rays`` returned, with ``position``, ``position_error`` and
    ``normal`` among its ``aovs``; ``directions`` broadcasts to its shape ``(..., 3)``.
    Each origin is the hit's ``position`` moved past its error box along the normal
    (by ``dot(|normal|, position_error)``, then each coordinate rounded one float further),
    on the side the direction leaves by: outward where ``dot(direction, normal) >= 0``,
    into the solid (or through a tube's wall) where it is negative, as pbrt-v4 spawns
    rays. Cast from there with ``t_min=0`` and the same kernel precision, a ray leaving
    outward never finds the surface it left, and one going inward finds the far wall.
    Rows of misses (normal 0) are NaN, which ``cast_rays`` refuses: select hits first.

    Example::

        hit = cylaov.cast_rays(scene, o, d, aovs=("t_hit", "normal", "position", "position_error"))
        ok = np.isfinite(hit["t_hit"])
        sub = {k: v[ok] for k, v in hit.items()}
        o2 = cylaov.spawn_rays(sub, d2[ok])
        nxt = cylaov.cast_rays(scene, o2, d2[ok])
    """
    missing = [k for k in ("position", "position_error", "normal") if k not in hits]
    if missing:
        raise ValueError(f"hits: needs {', '.join(missing)} (ask cast_rays for them in aovs)")
    p = _np.asarray(hits["position"], dtype=_np.float64)
    try:
        d = _np.broadcast_to(_np.asarray(directions, dtype=_np.float64), p.shape)
        e = _np.broadcast_to(_np.asarray(hits["position_error"], dtype=_np.float64), p.shape)
        n = _np.broadcast_to(_np.asarray(hits["normal"], dtype=_np.float64), p.shape)
    except ValueError as err:
        raise ValueError(f"directions and hits must broadcast to {p.shape}: {err}") from None
    flat = lambda a: _np.ascontiguousarray(a.reshape(-1, 3))
    return _cylaov._spawn_rays(flat(p), flat(e), flat(n), flat(d)).reshape(p.shape)


@_checked()
def write_shards(input, out, shards=None, shard_size=1000, aovs=None, members=None,
                 precision="f64", formula="stable", depth_scale=1000.0, threads=None,
                 force=False):
    """Write tar shards ``shards`` (indices; None: all) as ``cylaov batch INPUT --out OUT
    --format webdataset`` does, the same bytes; returns ``{"tars", "written", "skipped",
    "failed", "index_written", "problems"}`` (``problems``: what could not be cleaned up).

    ``input`` is what ``batch`` takes (a folder of scene files, a ``generate`` output, a
    ``.jsonl`` manifest; one scene file is refused, as ``batch`` refuses it), or scenes in
    memory: one
    ``Scene``, a list of them (keys ``scene_000000``, ``scene_000001``, ... in order) or a
    dict ``{key: Scene}`` (each key names its views' samples, as a scene file's stem does).
    Scenes in memory are written as ``OUT/scenes/KEY.json`` (with ``manifest.jsonl`` listing
    them in the order a folder's scan takes them: the same tars), the dataset's input, which
    ``shards.json`` records, so ``cylaov verify OUT`` reads them and equal calls write equal
    bytes; a call with other scenes replaces them (a refused call leaves them). A rerun with
    equal scenes skips the tars already finished, as a rerun of ``batch`` does; calls that
    write tars of one dataset side by side pass the same scenes. An ``OUT/scenes`` that
    this function did not write is refused, never replaced.

    Ctrl-C stops it with ``KeyboardInterrupt``, leaving the finished tars and no temporary
    file. ``out`` holds one dataset (``out/shards.settings.json``): a call with other
    settings (shard size, AOVs, members, inputs, kernel) raises ``ValueError`` naming each
    difference, unless ``force=True``, which removes that dataset's tar-shard files first.

    Example::

        scenes = [cylaov.generate(None, seed=7, index=i) for i in range(100)]
        cylaov.write_shards(scenes, "shards", shard_size=25, aovs=("depth", "normal"))
    """
    named = _scene_files(input)
    args = (shards, shard_size, aovs, members, precision, formula, depth_scale, threads, force)
    if named is None:
        return _cylaov.write_shards(input, out, *args)
    out = _os.fsdecode(out) if isinstance(out, bytes) else _os.fspath(out)
    if not out:
        raise ValueError("out: must name a folder, got '' (use '.' for the working folder)")
    files = {key + ".json": scene.to_json().encode() for key, scene in named.items()}
    # Read through a manifest: `batch` does not scan a folder inside its output for scene
    # files (they could be its own outputs), but it reads the files a manifest lists. In
    # the order a scan of the folder takes them (by name, bytewise): the same tars.
    order = sorted(files, key=lambda n: n.encode("utf-8"))
    files["manifest.jsonl"] = "".join(
        _json.dumps({"scene": n}, ensure_ascii=False) + "\n" for n in order).encode("utf-8")
    folder = _os.path.join(out, "scenes")
    try:
        return _SceneFolder(out, folder, files).call(
            lambda: _cylaov.write_shards(folder, out, *args))
    except ValueError as e:
        message = str(e)
        for path in (folder, _os.path.abspath(folder)):
            message = _keys_for_files(message, path, named)
        if message == str(e):
            raise
        raise type(e)(message) from None


# The file that marks `OUT/scenes` as written by `write_shards` (hidden: not a scene).
_SCENES_MARK = ".cylaov-write-shards"


class _SceneFolder:
    """``OUT/scenes`` holding exactly ``files`` (name: bytes) for the call made inside.

    Left as it is when it holds them already (a rerun, or workers writing tars of one
    dataset side by side); else the new files are written to a hidden folder in ``OUT``
    and swapped in whole, the old folder kept aside: it comes back if the call is refused
    (a ``ValueError`` with ``shards.settings.json`` unchanged: the old dataset stays with
    its scenes, and an ``OUT`` made for the call goes again), and is removed otherwise."""

    def __init__(self, out, folder, files):
        self.out, self.folder, self.files = out, folder, files

    def call(self, work):
        """``work()`` with the folder in place."""
        import shutil

        have = self._held()
        if have == self.files:
            return work()
        made_out = not _os.path.lexists(self.out)
        _os.makedirs(self.out, exist_ok=True)
        stage = _tempfile.mkdtemp(prefix=".scenes-", dir=self.out)
        aside = None
        try:
            for name, data in self.files.items():
                with open(_os.path.join(stage, name), "wb") as f:
                    f.write(data)
            with open(_os.path.join(stage, _SCENES_MARK), "w", encoding="utf-8") as f:
                f.write("The scene files cylaov.write_shards wrote for the scenes in memory it "
                        "was given: this dataset's input. Its next call with other scenes "
                        "replaces them.\n")
            settings = self._settings()
            if have is not None:
                aside = _tempfile.mkdtemp(prefix=".scenes-old-", dir=self.out)
                _os.rename(self.folder, _os.path.join(aside, "scenes"))
            try:
                _os.rename(stage, self.folder)
            except OSError:
                # Another call put its folder there first: the same scenes do.
                if self._held() != self.files:
                    raise
                shutil.rmtree(stage, ignore_errors=True)
            stage = None
            try:
                return work()
            except ValueError:
                if self._settings() == settings:
                    # Refused: OUT as it was (its old scenes back, or none, or no OUT).
                    gone = _tempfile.mkdtemp(prefix=".scenes-", dir=self.out)
                    _os.rename(self.folder, _os.path.join(gone, "scenes"))
                    if aside is not None:
                        _os.rename(_os.path.join(aside, "scenes"), self.folder)
                    shutil.rmtree(gone, ignore_errors=True)
                    if made_out:
                        try:
                            _os.rmdir(self.out)
                        except OSError:
                            pass
                raise
        finally:
            if stage is not None:
                shutil.rmtree(stage, ignore_errors=True)
            if aside is not None:
                shutil.rmtree(aside, ignore_errors=True)

    def _held(self):
        """What ``OUT/scenes`` holds (name: bytes; None when absent); ``ValueError`` when it
        is there but not this function's."""
        try:
            names = _os.listdir(self.folder)
        except FileNotFoundError:
            if _os.path.lexists(self.folder):
                raise ValueError(f"out: {self.folder} is a broken link; scenes in memory are "
                                 "written there: remove it or choose another out") from None
            return None
        except NotADirectoryError:
            raise ValueError(f"out: {self.folder} is not a folder; scenes in memory are "
                             "written there: remove it or choose another out") from None
        if _os.path.islink(self.folder) or _SCENES_MARK not in names:
            raise ValueError(f"out: {self.folder} was not written by write_shards (it has no "
                             f"{_SCENES_MARK}); scenes in memory are written there: choose "
                             "another out, or move that folder")
        held = {}
        for name in names:
            if name == _SCENES_MARK:
                continue
            path = _os.path.join(self.folder, name)
            if _os.path.islink(path) or not _os.path.isfile(path):
                held[name] = None
                continue
            with open(path, "rb") as f:
                held[name] = f.read()
        return held

    def _settings(self):
        try:
            with open(_os.path.join(self.out, "shards.settings.json"), "rb") as f:
                return f.read()
        except OSError:
            return None


def _keys_for_files(message, tmp, named):
    """``message`` naming the scenes in memory by their keys (``input['a.b']``) where it
    names the scene files written for them in ``OUT/scenes``, which the user never wrote."""
    if tmp not in message:
        return message
    prefix = _re.escape(_os.path.join(tmp, ""))

    def key(m):
        k = m.group(1)
        return f"input[{k!r}]" if k in named else m.group(0)

    message = _re.sub(prefix + r"([^/()]+?)\.json(?=[:)])", key, message)
    return message.replace("rename the scene files or give them manifest names",
                           "rename the keys")


# The longest key: a scene file's name (KEY.json) takes at most 255 bytes on most file
# systems.
_KEY_BYTES = 255 - len(".json")


def _scene_files(input):
    """``{key: Scene}`` for scenes in memory (one, a list, a dict); None for a path."""
    if isinstance(input, Scene):
        return {"scene_000000": input}
    if isinstance(input, (str, bytes, _os.PathLike)):
        return None
    if isinstance(input, dict):
        items = list(input.items())
    else:
        try:
            items = [("scene_%06d" % i, s) for i, s in enumerate(input)]
        except TypeError:
            raise TypeError(
                "input: a path, a Scene, a list of Scenes or a dict of them, got "
                f"{type(input).__name__}"
            ) from None
    if not items:
        raise ValueError("input: no scenes (an empty list or dict)")
    for key, scene in items:
        if not isinstance(key, str):
            raise TypeError(f"input: keys must be str, got {_described(key)}")
        shown = _shorten(repr(key))
        if not isinstance(scene, Scene):
            raise TypeError(f"input[{shown}]: a Scene, got {type(scene).__name__}")
        if not key or key in (".", "..") or "/" in key or "\\" in key or "\0" in key:
            raise ValueError(f"input: key {shown} cannot name a scene file")
        if key.startswith("."):
            raise ValueError(f"input: key {shown} starts with a dot, which hides a file: "
                             "a scene file's name cannot")
        try:
            size = len(key.encode("utf-8"))
        except UnicodeEncodeError:
            raise ValueError(f"input: key {shown} is not valid text (a lone surrogate) and "
                             "cannot name a scene file") from None
        if size > _KEY_BYTES:
            raise ValueError(f"input: key {shown} is {size} bytes of UTF-8; a scene file's "
                             f"name takes at most {_KEY_BYTES} (and .json)")
    return dict(items)


def _names(names, what):
    """One name or a sequence of names as a tuple; anything else raises ``TypeError(what)``."""
    if isinstance(names, str):
        return (names,)
    try:
        names = tuple(names)
    except TypeError:
        raise TypeError(what) from None
    if not all(isinstance(n, str) for n in names):
        raise TypeError(what)
    return names


def _settings_json(settings):
    """``generate.json``'s keys as JSON text: a dict, a path to that file, or None."""
    if settings is None:
        return None
    if isinstance(settings, (str, bytes, _os.PathLike)):
        with open(settings, encoding="utf-8") as f:
            return f.read()
    if not isinstance(settings, dict):
        raise TypeError(f"settings: a dict, a path to generate.json or None, got {type(settings).__name__}")
    return _json_text(settings, "settings")


def _json_text(value, name):
    """``value`` as JSON text: dicts with ``str`` keys, lists, tuples, strings, finite
    numbers, bools and None, numpy scalars and arrays taken as their Python values.
    Anything else raises ``ValueError`` (a NaN or an infinity, which JSON cannot hold) or
    ``TypeError`` naming where it lies, ``settings['fov']: must be a finite number, got
    float nan``, where ``json`` names neither."""

    def plain(v, at):
        if isinstance(v, (_np.generic, _np.ndarray)):
            v = v.tolist()
        if v is None or isinstance(v, (bool, int, str)):
            return v
        if isinstance(v, float):
            if not _math.isfinite(v):
                raise ValueError(f"{at}: must be a finite number, got {_described(v)}")
            return v
        if isinstance(v, dict):
            out = {}
            for k, x in v.items():
                if not isinstance(k, str):
                    raise TypeError(f"{at}: keys must be str, got {_described(k)}")
                out[k] = plain(x, f"{at}[{_shorten(repr(k))}]")
            return out
        if isinstance(v, (list, tuple)):
            return [plain(x, f"{at}[{i}]") for i, x in enumerate(v)]
        raise TypeError(f"{at}: not JSON data (a dict, list, str, finite number, bool or "
                        f"None), got {_described(v)}")

    return _json.dumps(plain(value, name), allow_nan=False)


def generate(settings, seed, index):
    """The scene ``cylaov generate`` writes for ``seed`` and ``index`` (0-based).

    ``settings`` holds the keys of ``generate.json`` (or of ``generate --config``): a dict,
    a path to such a file, or ``None`` for the defaults. Its ``count`` is ignored; a ``seed``
    in it that differs from the argument raises ``ValueError``. A pure function of its
    arguments: the same scene in any process, worker or machine.
    """
    return _cylaov._generate(_settings_json(settings), seed, index)


class Dataset:
    """Generated views rendered on the fly: a map-style dataset (PyTorch's ``Dataset``
    protocol, without importing torch).

    ``length`` counts views (at most ``2**63 - 1``, what ``len()`` can return);
    ``views_per_scene=None`` takes the settings' ``views_per_scene``, else 1 (given, it must
    agree with the settings). With ``views_per_scene = V``, item ``i`` is camera ``i % V`` of
    generated scene ``i // V`` (``generate(settings, seed, i // V)`` with V cameras). An item
    is the dict of ``render`` (``aovs`` and ``mask``) plus ``"camera_info"``; it depends on
    ``(settings, seed, i)`` alone, so every worker and process gets the same item ``i``
    (for V = 1 it equals ``render(generate(settings, seed, i), aovs)``).

    ``threads=None`` renders on every core; inside ``DataLoader(num_workers=k)`` workers
    pass ``threads=1`` so k workers do not fight over the cores. Works in forked workers
    (each process builds its own thread pool) and pickles for spawned ones. Making one sets
    glibc's allocator to keep freed memory for reuse, as the ``cylaov`` command does, so
    each view's buffers land on pages already mapped (a third of a small view's time).

    Example::

        ds = cylaov.Dataset(None, seed=0, length=1000, aovs=("depth", "normal"))
        loader = torch.utils.data.DataLoader(ds, batch_size=8, num_workers=2)
    """

    def __init__(self, settings, seed, length, aovs=("depth", "normal"), views_per_scene=None,
                 threads=None):
        self.settings = settings
        self.aovs = _names(aovs, "aovs: an AOV name or a sequence of AOV names")
        # The numbers are checked there (an integer in range, else an error naming it).
        self._views = _cylaov._Views(_settings_json(settings), seed, length, list(self.aovs),
                                     views_per_scene, threads)
        self.seed = _operator.index(seed)
        self.length = _operator.index(length)
        # None: the settings' `views_per_scene`, else 1.
        self.views_per_scene = self._views.views_per_scene
        self.threads = None if threads is None else _operator.index(threads)

    def __len__(self):
        return self.length

    def __getitem__(self, i):
        return self._views.item(self._position(i))

    def __getitems__(self, indices):
        """Items ``indices`` as a list, rendered in one call on the pool: PyTorch's
        ``DataLoader`` calls this once per batch, so a batch costs one trip, and its small
        views render side by side. Each item equals ``self[i]``.

        The items' arrays lie back to back in one buffer, each key's arrays forming the
        batch PyTorch's default collation would stack them into: collation then takes that
        buffer as it is (no copy), and a worker of a ``DataLoader`` hands it to the main
        process as one shared-memory block, reused once the batch is freed there."""
        indices = [self._position(i) for i in indices]
        if not indices:
            return _Items()
        _register_collation()
        layout = self._layout()
        offsets, size = _offsets(layout, len(indices))
        buffer, shared = _BUFFERS.take(size)
        infos = self._views.items_into(indices, buffer, [o for o, _ in offsets])
        items = _Items()
        for j, info in enumerate(infos):
            item = _Item()
            for (name, dtype, shape), (off, nbytes) in zip(layout, offsets):
                start = off + j * nbytes
                item[name] = buffer[start:start + nbytes].view(dtype).reshape(shape)
            item["camera_info"] = info
            items.append(item)
        items._batch = (buffer, shared, layout, offsets, tuple(dict(it) for it in items))
        return items

    def _position(self, i):
        """Index ``i`` (negative counts from the end) as a view number; ``IndexError`` out of
        range, however large (the views take 64-bit numbers)."""
        k = _index(i)
        n = self.length
        if not -n <= k < n:
            raise IndexError(f"index {k} out of range for a dataset of {n} views")
        return k + n if k < 0 else k

    def _layout(self):
        layout = self.__dict__.get("_layout_cache")
        if layout is None:
            layout = [(name, _np.dtype(dtype), tuple(shape))
                      for name, dtype, shape in self._views.layout()]
            self._layout_cache = layout
        return layout

    def __iter__(self):
        for i in range(self.length):
            yield self._views.item(i)

    def __reduce__(self):
        return (Dataset, (self.settings, self.seed, self.length, self.aovs,
                          self.views_per_scene, self.threads))

    def __repr__(self):
        return (f"cylaov.Dataset(seed={self.seed}, length={self.length}, aovs={self.aovs}, "
                f"views_per_scene={self.views_per_scene})")


class _Item(dict):
    """An item of ``Dataset.__getitems__``: a plain dict, whose type tells PyTorch's default
    collation (``_collate``) that its arrays may lie in a batch buffer already."""

    __slots__ = ()

    def __reduce__(self):
        # A plain dict elsewhere: each array pickles its own bytes, not the batch's buffer.
        return (dict, (dict(self),))


class _Items(list):
    """The list ``Dataset.__getitems__`` returns, with its batch buffer: ``(buffer, shared,
    layout, offsets, items as made)``, so collation can tell whether the items are still
    those arrays."""

    __slots__ = ("_batch",)

    def __init__(self, *args):
        super().__init__(*args)
        self._batch = None

    def __reduce__(self):
        return (list, (list(self),))


# A batch buffer starts with a header: its first 8 bytes are 1 while a DataLoader's main
# process holds the batch, which lets the worker that wrote it reuse it afterwards.
_HEADER = 64


def _offsets(layout, n):
    """Each array block's ``(offset, bytes an item)`` in a buffer of ``n`` items, and the
    buffer's size: blocks after the header, each 64-byte aligned."""
    out, at = [], _HEADER
    for _, dtype, shape in layout:
        nbytes = dtype.itemsize * int(_np.prod(shape))
        out.append((at, nbytes))
        at += -(-nbytes * n // 64) * 64
    return out, at


class _Buffers:
    """This process's batch buffers, reused once nothing holds the batch made in one: its
    pages are then mapped already, where a fresh buffer a batch would fault each page in
    (in shared memory, as much time as the views' rendering). In a DataLoader worker they
    are shared memory (torch's), elsewhere plain numpy memory."""

    # A worker holds at most its DataLoader's prefetched batches (2 by default), the one
    # the main process uses and the one it writes: more are kept only while in use.
    KEEP = 4

    def __init__(self):
        self.pid = None
        self.entries = []  # [owner, shared tensor or None, weak ref to the last batch's array]
        self.lock = None

    def take(self, size):
        """A buffer of at least ``size`` bytes no batch holds: ``(uint8 array, shared
        storage tensor or None)``; the array's views keep it from reuse while alive."""
        if self.pid != _os.getpid():
            # Inherited through fork: the parent's buffers are its own (copied on write),
            # and its lock may have been held by a thread that the child does not have.
            self.pid, self.entries, self.lock = _os.getpid(), [], _threading.Lock()
        # Threads calling `__getitems__` at once (the GIL is released while views render)
        # must not both take the same free buffer.
        with self.lock:
            return self._take(size)

    def _take(self, size):
        shared = _in_worker()
        for e in self.entries:
            owner, tensor, ref = e
            if (tensor is not None) == shared and owner.size >= size and ref() is None \
                    and _flag(owner) == 0:
                break
        else:
            if shared:
                import torch

                tensor = torch.empty(size, dtype=torch.uint8).share_memory_()
                owner = tensor.numpy()
            else:
                tensor, owner = None, _np.empty(size, dtype=_np.uint8)
            _flag(owner, 0)
            e = [owner, tensor, None]
            self.entries.append(e)
            if len(self.entries) > self.KEEP:
                # A free one first (memory, shared memory in a worker, kept for nothing);
                # else the oldest, which lives on while its batch does.
                idle = [x for x in self.entries if x[2] is not None and x[2]() is None
                        and _flag(x[0]) == 0]
                # By identity: `list.remove` would compare the entries with `==`, which
                # on their numpy arrays is elementwise (and raises).
                victim = idle[0] if idle else self.entries[0]
                del self.entries[next(k for k, x in enumerate(self.entries) if x is victim)]
        # A view through a memoryview: the arrays made from it keep it, not the owner, as
        # their base, so the weak reference tells when the last of them is gone.
        buffer = _np.frombuffer(memoryview(e[0]), dtype=_np.uint8)
        e[2] = _weakref.ref(buffer)
        return buffer, e[1]


_BUFFERS = _Buffers()


def _flag(buffer, value=None):
    """The header's in-use flag of a batch buffer; set to ``value`` if given."""
    word = buffer[:8].view(_np.uint64)
    if value is not None:
        word[0] = value
    return int(word[0])


def _in_worker():
    """Whether this process is a worker of a PyTorch DataLoader (torch imported)."""
    torch = _sys.modules.get("torch")
    if torch is None:
        return False
    try:
        return torch.utils.data.get_worker_info() is not None
    except AttributeError:
        return False


_REGISTERED = False


def _register_collation():
    """Teach PyTorch's default collation (``default_collate_fn_map``, its documented
    extension point) that a batch of ``_Item``s is its buffer: done once torch is loaded."""
    global _REGISTERED
    if _REGISTERED or "torch" not in _sys.modules:
        return
    try:
        from torch.utils.data._utils.collate import default_collate_fn_map
    except ImportError:
        return
    default_collate_fn_map[_Item] = _collate
    _REGISTERED = True


def _collate(batch, *, collate_fn_map=None):
    """PyTorch's default collation of items of ``Dataset.__getitems__``: the same tensors,
    bit for bit, taken from the batch buffer when the items are still its arrays (else
    collated as plain dicts)."""
    from torch.utils.data._utils.collate import collate, default_collate_fn_map

    made = getattr(batch, "_batch", None)
    if made is None or collate_fn_map is not default_collate_fn_map or not _unchanged(batch, made):
        return collate([dict(x) for x in batch], collate_fn_map=collate_fn_map)
    buffer, shared, layout, offsets, _ = made
    out = _tensors(buffer, layout, offsets, len(batch))
    out["camera_info"] = collate([x["camera_info"] for x in batch], collate_fn_map=collate_fn_map)
    if shared is not None and _in_worker():
        return _SharedBatch(out, shared, buffer, layout, offsets, len(batch))
    return out


def _unchanged(batch, made):
    """Whether ``batch`` holds the items ``__getitems__`` made, each with the same arrays."""
    first = made[4]
    if type(batch) is not _Items or len(batch) != len(first):
        return False
    for item, was in zip(batch, first):
        if type(item) is not _Item or item.keys() != was.keys():
            return False
        for k, v in was.items():
            if item[k] is not v:
                return False
    return True


def _tensors(buffer, layout, offsets, n):
    """The batch tensors of a buffer's arrays: ``{name: (n, *shape)}``."""
    import torch

    out = {}
    for (name, dtype, shape), (off, nbytes) in zip(layout, offsets):
        block = buffer[off:off + n * nbytes].view(dtype).reshape((n,) + shape)
        out[name] = torch.from_numpy(block)
    return out


class _SharedBatch(dict):
    """A collated batch in a DataLoader worker: the dict default collation makes, which
    pickles (to the main process) as its shared buffer, sent once, and the camera fields as
    a few numpy arrays, instead of one shared-memory block a tensor. Unpickled, it is that plain
    dict again. A changed dict pickles as a dict."""

    __slots__ = ("_made",)

    def __init__(self, out, shared, buffer, layout, offsets, n):
        super().__init__(out)
        self._made = (dict(out), shared, buffer, layout, offsets, n)

    def __reduce__(self):
        was, shared, buffer, layout, offsets, n = self._made
        if self.keys() != was.keys() or any(self[k] is not v for k, v in was.items()):
            return (dict, (list(self.items()),))
        _flag(buffer, 1)
        return (_rebuild, (shared, layout, offsets, n, _pack(self["camera_info"])))


def _rebuild(shared, layout, offsets, n, info):
    """A worker's batch in the main process: tensors over the shared buffer, which is
    flagged free for the worker again once the last of them is freed."""
    import torch

    owner = shared.numpy()
    buffer = _np.frombuffer(memoryview(owner), dtype=_np.uint8)
    _weakref.finalize(buffer, _flag, owner, 0)
    out = _tensors(buffer, layout, offsets, n)
    out["camera_info"] = _unpack(info, torch)
    return out


def _pack(info):
    """Collated camera fields for pickling: the tree with each tensor replaced by its
    number, and the tensors stacked by dtype, ``[(numpy (n, B) array, numbers)]``: a few
    arrays to pickle and rebuild instead of one a field."""
    leaves = []

    def number(x):
        if hasattr(x, "numpy"):
            leaves.append(x)
            return len(leaves) - 1
        return x

    tree = _map_leaves(info, number)
    import torch

    groups = {}
    for j, t in enumerate(leaves):
        groups.setdefault((t.dtype, t.shape), []).append(j)
    stacks = [(torch.stack([leaves[j] for j in js]).numpy(), js) for js in groups.values()]
    return tree, stacks


def _unpack(packed, torch):
    """``_pack`` undone: the same tensors, each a row of its stack."""
    tree, stacks = packed
    leaves = {}
    for array, js in stacks:
        leaves.update(zip(js, torch.from_numpy(array).unbind(0)))

    return _map_leaves(tree, lambda x: leaves[x] if type(x) is int else x)


def _map_leaves(x, leaf):
    """The collated tree ``x`` (dicts and lists) with ``leaf`` applied to each leaf; a list of
    strings (collated strings: the items' own) is a leaf left as it is."""
    t = type(x)
    if t is dict:
        return {k: _map_leaves(v, leaf) for k, v in x.items()}
    if t is list:
        return x if x and type(x[0]) is str else [_map_leaves(v, leaf) for v in x]
    return leaf(x)


def _index(i):
    try:
        return i.__index__()
    except AttributeError:
        raise TypeError(f"Dataset indices must be integers, got {type(i).__name__}") from None


def to_ply(arrays, path):
    """Write a render's hit points as a PLY point cloud, as ``cylaov render --ply`` does.

    ``arrays`` is what ``render`` returns with at least ``position``, ``normal`` and
    ``shape_id`` (``part`` and ``label`` are written as 0 when absent): one point per pixel
    whose ``shape_id`` is not 0, row by row. The file is binary little-endian PLY with
    ``x y z nx ny nz`` (float32, world axes) and ``shape_id part label`` (uint32), which
    Open3D's ``read_point_cloud`` reads. A link or FIFO at ``path`` is refused; the file is
    written whole or not at all. Returns the number of points.

    Example::

        out = cylaov.render(scene, aovs=("position", "normal", "shape_id", "part", "label"))
        cylaov.to_ply(out, "view.ply")
    """
    for key in ("position", "normal", "shape_id"):
        if key not in arrays:
            raise ValueError(
                "to_ply: arrays lacks %r; render with aovs including position, normal, "
                "shape_id" % key
            )
    ids = _np.asarray(arrays["shape_id"], dtype=_np.uint32)
    hit = ids != 0
    pos = _np.asarray(arrays["position"], dtype=_np.float32)
    nrm = _np.asarray(arrays["normal"], dtype=_np.float32)
    if pos.shape != ids.shape + (3,) or nrm.shape != ids.shape + (3,):
        raise ValueError(
            "to_ply: position and normal must have shape %r, got %r and %r"
            % (ids.shape + (3,), pos.shape, nrm.shape)
        )

    def extra(key):
        if key not in arrays:
            return _np.zeros(ids.shape, dtype=_np.uint32)
        a = _np.asarray(arrays[key], dtype=_np.uint32)
        if a.shape != ids.shape:
            raise ValueError(
                "to_ply: %s must have shape %r, got %r" % (key, ids.shape, a.shape)
            )
        return a

    table = _np.stack([ids[hit], extra("part")[hit], extra("label")[hit]], axis=-1)
    return _cylaov._write_ply(
        _np.ascontiguousarray(pos[hit]).reshape(-1),
        _np.ascontiguousarray(nrm[hit]).reshape(-1),
        _np.ascontiguousarray(table, dtype=_np.uint32).reshape(-1),
        _os.fspath(path),
    )
