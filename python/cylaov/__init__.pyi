"""Type stub of the cylaov package (see help(cylaov) and docs/python.md)."""

import os
from typing import Any, Dict, Iterator, Literal, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
AovName = Literal["distance", "depth", "normal", "position", "shape_id", "part", "normal_camera", "label", "uv"]
RayOutput = Literal["t_hit", "normal", "shape_id", "part", "position", "position_error"]
MemberName = Literal["exr", "depth.png", "ply"]
Settings = Union[None, Dict[str, Any], PathLike]

class SceneError(ValueError):
    """A refused scene; the text is the command line's error line without `error: `."""

class InternalError(RuntimeError):
    """A fault inside cylaov (a caught Rust panic): a bug to report."""

class Scene:
    """A validated cylinder scene (cylinders and one or more cameras)."""

    @staticmethod
    def load(path: PathLike) -> "Scene": ...
    @staticmethod
    def from_json(text: Union[str, bytes]) -> "Scene": ...
    @staticmethod
    def from_dict(d: Dict[str, Any]) -> "Scene": ...
    @staticmethod
    def from_table(
        path: PathLike,
        format: Optional[Literal["csv", "npz", "treeqsm", "simpleforest", "archi"]] = None,
        label: Optional[Literal["none", "branch_order", "branch", "segment"]] = None,
        caps: Optional[bool] = None,
    ) -> "Scene":
        """A scene from a cylinder table (TreeQSM, SimpleForest, aRchi or plain CSV), as
        `cylaov import` makes it, with one camera framing every cylinder."""
        ...
    @staticmethod
    def from_arrays(
        p0: npt.ArrayLike,
        p1: npt.ArrayLike,
        radius: npt.ArrayLike,
        caps: Union[bool, Sequence[bool], None] = None,
        ids: Optional[npt.ArrayLike] = None,
        camera: Optional[Dict[str, Any]] = None,
        cameras: Optional[Sequence[Dict[str, Any]]] = None,
    ) -> "Scene":
        """A scene from arrays: `p0`, `p1` (N, 3) end centres and `radius` (N,), any real
        array-likes (converted as `np.asarray(x, dtype=np.float64)`); `ids` N whole numbers
        in 1..=4294967295 of any dtype; exactly one of `camera` (a dict of the scene file's
        camera keys) and `cameras` (a list of them: `render(scene, camera=k)` picks one).

        Example::

            scene = cylaov.Scene.from_arrays(
                [[0, 0, 0]], [[0, 0, 1]], [0.5],
                cameras=[{"origin": [3, -5, 2.5], "target": [0, 0, 0.5], "up": [0, 0, 1],
                          "fov_deg": 40, "width": 64, "height": 48},
                         {"origin": [-3, 5, 2.5], "target": [0, 0, 0.5], "up": [0, 0, 1],
                          "fov_deg": 40, "width": 32, "height": 24}])
            depth = cylaov.render(scene, aovs="depth", camera=1)["depth"]   # (24, 32)
        """
        ...
    @property
    def cameras(self) -> list[Dict[str, Any]]: ...
    def to_json(self) -> str: ...
    def to_mitsuba_xml(self, source_name: str = "python") -> str: ...
    def __len__(self) -> int: ...

def render(
    scene: Scene,
    aovs: Union[AovName, Sequence[AovName]] = ("depth", "normal"),
    camera: int = 0,
    precision: Literal["f64", "f32"] = "f64",
    formula: Literal["stable", "literal"] = "stable",
    accel: Literal["tiles", "frustum", "bvh"] = "tiles",
    threads: Optional[int] = None,
) -> Dict[str, np.ndarray]: ...
def camera_info(scene: Scene, camera: int = 0) -> Dict[str, Any]: ...
def camera_rays(
    scene: Scene, camera: int = 0
) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
def cast_rays(
    scene: Scene,
    origins: npt.ArrayLike,
    directions: npt.ArrayLike,
    t_min: npt.ArrayLike = 0.0,
    t_max: npt.ArrayLike = float("inf"),
    aovs: Union[RayOutput, Sequence[RayOutput]] = ("t_hit", "normal", "shape_id", "part"),
    precision: Literal["f64", "f32"] = "f64",
    formula: Literal["stable", "literal"] = "stable",
    threads: Optional[int] = None,
) -> Dict[str, np.ndarray]: ...
def spawn_rays(hits: Dict[str, np.ndarray], directions: npt.ArrayLike) -> np.ndarray: ...
def scan(
    scene: Union[Scene, PathLike],
    sensor: Union[str, PathLike, Dict[str, Any]],
    pose: Optional[Sequence[float]] = None,
    trajectory: Union[PathLike, npt.ArrayLike, None] = None,
    returns: int = 1,
    range_noise: float = 0.0,
    dropout: float = 0.0,
    seed: int = 0,
    threads: Optional[int] = None,
) -> Dict[str, np.ndarray]: ...
def generate(settings: Settings, seed: int, index: int) -> Scene: ...
def read(path: PathLike) -> Dict[str, Any]: ...
def to_ply(arrays: Dict[str, Any], path: PathLike) -> int: ...
def compare(
    a: Union[PathLike, Dict[str, np.ndarray]],
    b: Union[PathLike, Dict[str, np.ndarray]],
    *,
    max_mismatch_fraction: float = ...,
    max_seam_fraction: float = ...,
    rel_distance: float = ...,
    rel_depth: float = ...,
    normal_deg: float = ...,
    scene: Union[Scene, PathLike, None] = None,
    conditioning_ulps: float = ...,
) -> Dict[str, Any]: ...

class Dataset:
    """Generated views rendered on the fly (a map-style, PyTorch-compatible dataset)."""

    settings: Settings
    seed: int
    length: int
    aovs: Tuple[AovName, ...]
    views_per_scene: int
    threads: Optional[int]
    def __init__(
        self,
        settings: Settings,
        seed: int,
        length: int,
        aovs: Union[AovName, Sequence[AovName]] = ("depth", "normal"),
        views_per_scene: Optional[int] = None,
        threads: Optional[int] = None,
    ) -> None: ...
    def __len__(self) -> int: ...
    def __getitem__(self, i: int) -> Dict[str, Any]: ...
    def __getitems__(self, indices: Sequence[int]) -> list[Dict[str, Any]]: ...
    def __iter__(self) -> Iterator[Dict[str, Any]]: ...

def shard_count(input: PathLike, shard_size: int = 1000) -> int:
    """The number of tar shards `cylaov batch INPUT --format webdataset` makes."""
    ...
def write_shards(
    input: Union[PathLike, Scene, Sequence[Scene], Mapping[str, Scene]],
    out: PathLike,
    shards: Optional[Sequence[int]] = None,
    shard_size: int = 1000,
    aovs: Union[AovName, Sequence[AovName], None] = None,
    members: Union[MemberName, Sequence[MemberName], None] = None,
    precision: Literal["f64", "f32"] = "f64",
    formula: Literal["stable", "literal"] = "stable",
    depth_scale: float = 1000.0,
    threads: Optional[int] = None,
    force: bool = False,
) -> Dict[str, Any]:
    """Write tar shards `shards` (None: all) as `batch --format webdataset` does, same bytes;
    returns {"tars", "written", "skipped", "failed", "index_written", "problems"}. `input` is a folder or a
    .jsonl manifest as `batch` takes it (not one scene file), or scenes in memory: a Scene, a list (keys scene_000000, ...) or a dict
    {key: Scene}, written as OUT/scenes/KEY.json (the input `cylaov verify OUT` reads). Ctrl-C stops it with
    KeyboardInterrupt, leaving the finished tars (a rerun skips them) and no temporary file.
    `out` holds one dataset (`out/shards.settings.json`): a call with other settings (shard
    size, AOVs, members, inputs, kernel) raises ValueError naming each difference, unless
    `force=True`, which removes that dataset's tar-shard files first."""
    ...
