"""The rendered dataset on disk: writing it (in parallel, reproducibly) and reading it back.

Layout of a dataset folder ``ROOT``::

    ROOT/dataset.json                       manifest: schema, generator settings, scene list
    ROOT/annotations/SCENE.json             one per scene: people, cameras and labels per frame
    ROOT/images/top/SCENE_FRAME.jpg         top/overview view (FRAME is 1-based, 6 digits)
    ROOT/images/ego/SCENE_FRAME.jpg         egocentric view

Both JSON files carry ``"schema"`` and ``"version"`` (:data:`SCHEMA_VERSION`); a reader refuses a
version it does not know. The scene file holds, per frame and view, the image path (relative to
``ROOT``), the camera (``K``, ``R``, ``c``, ``width``, ``height`` in the convention of
:class:`~xvmatch.geometry.camera.Camera`) and one record per visible person (the fields of
:class:`~xvmatch.datasets.render.image_render.ViewLabels`). ``docs/synthetic_data.md``
documents every field.

Scene ``i`` of a dataset with seed ``S`` is drawn from ``numpy.random.default_rng([S, i])``
alone, so the files are byte-identical for any number of workers. The whole folder is written
atomically (a temporary folder beside it, moved into place at the end), the manifest last: a
dataset with a manifest is complete, and only a folder this module wrote is ever replaced.

Reading goes through :class:`SyntheticDataset` (pairs, per-scene box tracks for the box-level
methods and the detector noise) and :func:`person_crops` (the crops the appearance branch trains
on), so training and evaluation see the same data the same way. Malformed files raise
:class:`SchemaError`, whose one-line message names the file and the field.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_bytes, atomic_write_text
from xvmatch.core.input_files import (
    MAX_INPUT_BYTES,
    InputFileError,
    check_input_file,
    read_input_text,
)
from xvmatch.core.json_text import parse_json
from xvmatch.core.worker_pool import worker_pool
from xvmatch.datasets.render.image_render import Difficulty, SceneRenderer, ViewLabels
from xvmatch.datasets.synthetic_scenes import SynthConfig, make_scene
from xvmatch.formats.crops import box_crops
from xvmatch.formats.image_size import check_image_size
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import Camera

__all__ = [
    "GENERATOR",
    "MANIFEST",
    "MOT_FOLDER",
    "SCHEMA_NAME",
    "SCHEMA_VERSION",
    "VIEWS",
    "PairRecord",
    "SceneInputs",
    "SceneRecord",
    "SchemaError",
    "SyntheticDataset",
    "ViewRecord",
    "draw_pair",
    "generate_dataset",
    "person_crops",
    "read_scene",
    "resolve_pair",
    "scene_name",
    "write_scene",
    "write_scene_inputs",
]

SCHEMA_NAME = "xvmatch.synthetic"
"""``"schema"`` of a scene annotation file; the manifest's is ``SCHEMA_NAME + ".dataset"``."""
SCHEMA_VERSION = 1
"""Version of both JSON files; bumped on any incompatible change."""
MANIFEST = "dataset.json"
GENERATOR = "xvmatch synth"
"""``"generator"`` of a manifest: marks a folder this module wrote (and may replace)."""
MOT_FOLDER = "mot"
"""Folder of a dataset's scenes laid out as a user's data (``generate_dataset(mot_boxes=True)``,
what ``xvmatch synth`` writes): ``mot/SCENE/top.txt``, ``hor.txt`` (MOT boxes, ground-truth ids)
and ``cameras/`` (per-frame camera files), see :func:`write_scene_inputs`."""
_OWN_ENTRIES = frozenset({MANIFEST, "annotations", "images", MOT_FOLDER})
VIEWS: tuple[str, ...] = ("top", "ego")
"""View names: the top/overview view and the egocentric view."""


class SchemaError(ValueError):
    """A dataset file that does not follow the schema; the message is ``"FILE: FIELD: problem"``."""


# --------------------------------------------------------------------------------------------
# Writing


def scene_name(index: int) -> str:
    """Name of scene ``index``: ``s00000``, ``s00001``, ..."""
    return f"s{int(index):05d}"


def _image_path(view: str, scene: str, frame: int) -> str:
    return f"images/{view}/{scene}_{frame:06d}.jpg"


def _round(values: np.ndarray, digits: int) -> list:
    return np.round(np.asarray(values, dtype=float), digits).tolist()


def _labels_to_json(labels: ViewLabels) -> list[dict]:
    boxes, full = _round(labels.boxes, 2), _round(labels.full_boxes, 2)
    ground, head = _round(labels.ground, 4), _round(labels.head, 4)
    visible = _round(labels.visible, 4)
    return [
        {
            "id": int(labels.ids[k]),
            "box": boxes[k],
            "full_box": full[k],
            "visible": visible[k],
            "truncated": bool(labels.truncated[k]),
            "visible_pixels": int(labels.visible_pixels[k]),
            "ground": ground[k],
            "head": head[k],
        }
        for k in range(len(labels))
    ]


def _config_dict(config: SynthConfig) -> dict:
    return json.loads(json.dumps(asdict(config)))


def write_scene(
    root: str | os.PathLike,
    config: SynthConfig,
    index: int,
    n_frames: int,
    seed: int,
    difficulty: Difficulty | None = None,
) -> dict:
    """Render scene ``index`` of a dataset and write its images and annotation file.

    Args:
        root: dataset folder; ``images/top``, ``images/ego`` and ``annotations`` are created.
        config: scenario configuration.
        index: scene index; the scene is drawn from ``default_rng([seed, index])``.
        n_frames: frames of the scene.
        seed: dataset seed.
        difficulty: rendering difficulty (``None``: medium).

    Returns:
        The scene's manifest entry: name, annotation path, frames and people.
    """
    import cv2

    root = Path(root)
    name = scene_name(index)
    for sub in ("images/top", "images/ego", "annotations"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng([int(seed), int(index)])
    scene = make_scene(config, n_frames, rng)
    renderer = SceneRenderer(scene, rng, difficulty)
    people = scene.people
    frames = []
    for frame in range(1, scene.n_frames + 1):
        pair = renderer.render(frame)
        record: dict = {"frame": frame}
        for view in VIEWS:
            rendered = getattr(pair, view)
            rel = _image_path(view, name, frame)
            ok, buf = cv2.imencode(".jpg", rendered.image,
                                   [cv2.IMWRITE_JPEG_QUALITY, rendered.jpeg_quality])
            if not ok:  # pragma: no cover - OpenCV always encodes a valid uint8 image
                raise OSError(f"could not encode {rel}")
            atomic_write_bytes(root / rel, buf.tobytes(), fsync=False)
            record[view] = {
                "image": rel,
                "camera": rendered.camera.to_dict(),
                "people": _labels_to_json(rendered.labels),
            }
        frames.append(record)
    appearance = renderer.appearances.to_dicts(people.ids)
    doc = {
        "schema": SCHEMA_NAME,
        "version": SCHEMA_VERSION,
        "scene": name,
        "scenario": config.scenario,
        "seed": [int(seed), int(index)],
        "fps": float(config.fps),
        "n_frames": scene.n_frames,
        "area": round(float(scene.area), 4),
        "camera_wearer": int(people.ids[people.wearer]),
        "people": [
            {
                "id": int(people.ids[i]),
                "height": round(float(people.heights[i]), 4),
                "width": round(float(people.widths[i]), 4),
                "appearance": appearance[i],
            }
            for i in range(people.n_people)
        ],
        "buildings": [b.to_dict() for b in scene.buildings],
        "photometric": {v: renderer.photometric[v].to_dict() for v in VIEWS},
        "frames": frames,
    }
    annotation = f"annotations/{name}.json"
    atomic_write_text(root / annotation, json.dumps(doc, separators=(",", ":")) + "\n")
    return {"name": name, "annotation": annotation, "n_frames": scene.n_frames,
            "n_people": people.n_people}


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)


def _write_scene_task(args: tuple) -> dict:
    """Write one scene (``write_scene``'s arguments) and, when the last item is true, its
    boxes and cameras as a user's data under :data:`MOT_FOLDER` (read back from its file)."""
    *scene_args, mot_boxes = args
    entry = write_scene(*scene_args)
    if mot_boxes:
        root = Path(scene_args[0])
        write_scene_inputs(read_scene(root / entry["annotation"], root),
                           root / MOT_FOLDER / entry["name"])
    return entry


def _is_own_dataset(root: Path) -> bool:
    """Whether ``root`` holds only a dataset this module wrote (its manifest and folders)."""
    try:
        manifest = json.loads(_json_text(root / MANIFEST))
    except (OSError, ValueError, RecursionError):  # InputFileError is a ValueError
        return False
    if not isinstance(manifest, dict) or manifest.get("schema") != SCHEMA_NAME + ".dataset":
        return False
    if manifest.get("generator", GENERATOR) != GENERATOR:  # absent: written before the mark
        return False
    return all(p.name in _OWN_ENTRIES for p in root.iterdir())


def _check_output_folder(root: Path) -> None:
    """Refuse a target that is a file, or a non-empty folder that is not our own dataset."""
    if root.exists() and not root.is_dir():
        raise ValueError(f"{os.fspath(root)}: exists and is not a directory")
    if not root.is_dir() or not any(root.iterdir()):
        return
    if not (root / MANIFEST).is_file():
        raise ValueError(f"{os.fspath(root)}: not empty and not a synthetic dataset "
                         f"(no {MANIFEST}); choose an empty or new folder")
    if not _is_own_dataset(root):
        raise ValueError(f"{os.fspath(root)}: not a dataset written by {GENERATOR} (foreign "
                         f"{MANIFEST} or other files beside it); choose an empty or new folder")


def _move_into_place(tmp: Path, root: Path) -> None:
    """Replace ``root`` (absent, empty, or our own dataset) by the finished folder ``tmp``."""
    _check_output_folder(root)  # again: the folder may have changed while rendering
    old = None
    if root.is_dir():
        if any(root.iterdir()):
            old = root.with_name(f"{tmp.name}.old")
            root.rename(old)
        else:
            root.rmdir()
    try:
        tmp.rename(root)
    except BaseException:
        if old is not None and not root.exists():
            old.rename(root)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def generate_dataset(
    root: str | os.PathLike,
    config: SynthConfig,
    *,
    n_scenes: int,
    n_frames: int,
    seed: int,
    workers: int = 1,
    difficulty: Difficulty | None = None,
    progress: Callable[[int], None] | None = None,
    mot_boxes: bool = False,
) -> Path:
    """Render a whole dataset into ``root``, atomically as a folder.

    The scenes and the manifest are written into a temporary folder beside ``root``, which is
    moved into place at the end: an interrupted run leaves ``root`` as it was, and a re-run
    replaces the whole previous dataset (no stale scenes stay beside the new manifest).

    Args:
        root: output folder: created if missing; if it exists it must be empty or hold a
            previous dataset written by this function (nothing but its manifest, naming
            :data:`GENERATOR` and the format, and its ``annotations``/``images`` folders),
            which is replaced.
        config: scenario configuration.
        n_scenes: number of scenes (>= 1).
        n_frames: frames per scene (>= 1).
        seed: dataset seed; scene i uses ``default_rng([seed, i])``.
        workers: processes rendering scenes in parallel (1: in this process). The output does
            not depend on it.
        difficulty: rendering difficulty (``None``: medium).
        progress: called with the number of pairs written each time a scene is done.
        mot_boxes: also write each scene as a user's data, ``MOT_FOLDER/SCENE/`` (``top.txt``,
            ``hor.txt``, ``cameras/``: what ``xvmatch associate`` and ``evaluate`` read).

    Returns:
        The manifest path.
    """
    if int(n_scenes) < 1 or int(n_frames) < 1:
        raise ValueError(f"need at least 1 scene and 1 frame, got {n_scenes} scenes, "
                         f"{n_frames} frames")
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    difficulty = Difficulty() if difficulty is None else difficulty
    root = Path(root)
    _check_output_folder(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{root.name}.synth-", dir=root.parent))
    try:
        _render_into(tmp, config, int(n_scenes), int(n_frames), int(seed), int(workers),
                     difficulty, progress, bool(mot_boxes))
        _move_into_place(tmp, root)
    except BaseException:  # interrupted or failed: leave no half-written folder behind
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return root / MANIFEST


def _render_into(
    root: Path,
    config: SynthConfig,
    n_scenes: int,
    n_frames: int,
    seed: int,
    workers: int,
    difficulty: Difficulty,
    progress: Callable[[int], None] | None,
    mot_boxes: bool = False,
) -> None:
    """Render every scene into ``root`` and write the manifest last."""
    tasks = [(root, config, i, n_frames, seed, difficulty, mot_boxes) for i in range(n_scenes)]
    entries: list[dict] = []
    if workers == 1:
        for task in tasks:
            entries.append(_write_scene_task(task))
            if progress is not None:
                progress(entries[-1]["n_frames"])
    else:
        # "spawn": a forked child would inherit OpenCV's thread pool in whatever state the
        # parent left it, which can deadlock; fresh interpreters are safe and cost ~1 s.
        with worker_pool(workers, "spawn", _worker_init) as pool:
            futures = [pool.submit(_write_scene_task, task) for task in tasks]
            for future in as_completed(futures):
                entries.append(future.result())
                if progress is not None:
                    progress(entries[-1]["n_frames"])
    entries.sort(key=lambda e: e["name"])
    manifest = {
        "schema": SCHEMA_NAME + ".dataset",
        "version": SCHEMA_VERSION,
        "generator": GENERATOR,
        "scenario": config.scenario,
        "seed": seed,
        "n_scenes": n_scenes,
        "frames_per_scene": n_frames,
        "config": _config_dict(config),
        "difficulty": json.loads(json.dumps(difficulty.to_dict())),
        "scenes": entries,
    }
    atomic_write_text(root / MANIFEST, json.dumps(manifest, indent=1) + "\n")


# --------------------------------------------------------------------------------------------
# Reading and validation


class _Doc:
    """A JSON value together with its file and field path, for one-line schema errors."""

    def __init__(self, value, file: str, path: str = "") -> None:
        self.value, self.file, self.path = value, file, path

    def error(self, what: str) -> SchemaError:
        where = f"{self.file}: {self.path}" if self.path else self.file
        return SchemaError(f"{where}: {what}")

    def __getitem__(self, key: str | int) -> _Doc:
        sub = f"{self.path}.{key}" if isinstance(key, str) else f"{self.path}[{key}]"
        sub = sub.lstrip(".")
        if isinstance(key, str):
            if not isinstance(self.value, dict):
                raise self.error(f"expected an object, got {type(self.value).__name__}")
            if key not in self.value:
                raise SchemaError(f"{self.file}: {sub}: missing field")
        return _Doc(self.value[key], self.file, sub)

    def items(self) -> list[_Doc]:
        if not isinstance(self.value, list):
            raise self.error(f"expected a list, got {type(self.value).__name__}")
        return [self[k] for k in range(len(self.value))]

    def str(self) -> str:
        if not isinstance(self.value, str):
            raise self.error(f"expected a string, got {self.value!r}")
        return self.value

    def int(self, low: int | None = None) -> int:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(f"expected an integer, got {v!r}")
        if low is not None and v < low:
            raise self.error(f"expected an integer >= {low}, got {v}")
        return v

    def bool(self) -> bool:
        if not isinstance(self.value, bool):
            raise self.error(f"expected true or false, got {self.value!r}")
        return self.value

    def numbers(self, shape: tuple[int, ...]) -> np.ndarray:
        try:
            arr = np.array(self.value, dtype=float)
        except (TypeError, ValueError):
            raise self.error(f"expected numbers of shape {shape}, got {self.value!r}") from None
        if arr.shape != shape or any(isinstance(v, bool) for v in np.ravel(self.value)):
            raise self.error(f"expected numbers of shape {shape}, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise self.error("expected finite numbers")
        return arr

    def number(self, low: float = -np.inf, high: float = np.inf) -> float:
        v = self.value
        if isinstance(v, bool) or not isinstance(v, int | float) or not low <= v <= high:
            raise self.error(f"expected a number in [{low}, {high}], got {v!r}")
        return float(v)


def _json_text(path: Path) -> str:
    """A manifest or annotation file's text through
    :func:`~xvmatch.core.input_files.read_input_text`: a FIFO, a device or a file with a
    NUL byte is refused at once. Without its line bound: an annotation is written as one
    compact line, about 10 kB a frame, so a long scene's is tens of megabytes."""
    return read_input_text(path, max_line=MAX_INPUT_BYTES)


def _load_json(path: Path) -> object:
    """The JSON document of a manifest or annotation file (:func:`_json_text`); every problem
    is a one-line :class:`SchemaError`."""
    try:
        text = _json_text(path)
    except InputFileError as exc:
        raise SchemaError(str(exc)) from None
    except OSError as exc:
        raise SchemaError(f"{os.fspath(path)}: cannot read: {exc.strerror or exc}") from None
    return parse_json(text, os.fspath(path), SchemaError)  # syntax, nesting depth: one line


def _check_header(doc: _Doc, schema: str) -> None:
    if doc["schema"].str() != schema:
        raise doc["schema"].error(f"expected {schema!r}, got {doc.value['schema']!r}")
    version = doc["version"].int()
    if version != SCHEMA_VERSION:
        raise doc["version"].error(
            f"unsupported version {version}; this xvmatch reads version {SCHEMA_VERSION}"
        )


@dataclass(frozen=True, eq=False)
class ViewRecord:
    """One view of one labelled pair.

    Attributes:
        view: ``"top"`` or ``"ego"``.
        image_path: absolute path of the JPEG file.
        camera: the calibrated camera.
        labels: the people visible in the view.
    """

    view: str
    image_path: Path
    camera: Camera
    labels: ViewLabels

    def load_image(self) -> np.ndarray:
        """The image as ``(H, W, 3)`` uint8 BGR.

        Raises:
            OSError: the file cannot be read or decoded.
            ImageTooLargeError: its header declares too many pixels (checked before decoding).
        """
        import cv2

        where = os.fspath(self.image_path)
        try:
            data = np.fromfile(where, dtype=np.uint8)
        except OSError as exc:
            raise OSError(f"{where}: cannot read image ({exc.strerror or exc})") from None
        check_image_size(data, where)
        try:
            image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
        except cv2.error:
            image = None
        if image is None:
            raise OSError(f"{where}: cannot read image")
        return image


@dataclass(frozen=True, eq=False)
class PairRecord:
    """A labelled image pair: both views of one frame of one scene.

    Attributes:
        scene: scene name.
        frame: 1-based frame number.
        scenario: ``"drone"`` or ``"overview"``.
        camera_wearer: id of the person carrying the egocentric camera (in the top view only).
        top: the top/overview view.
        ego: the egocentric view.
    """

    scene: str
    frame: int
    scenario: str
    camera_wearer: int
    top: ViewRecord
    ego: ViewRecord


@dataclass(frozen=True, eq=False)
class SceneRecord:
    """A scene annotation file, parsed and validated.

    Attributes:
        name: scene name.
        path: the annotation file.
        scenario: ``"drone"`` or ``"overview"``.
        fps: frame rate of the walks.
        camera_wearer: id of the egocentric camera's carrier.
        people: per-person records (``id``, ``height``, ``width``, ``appearance``).
        pairs: the frames, ``pairs[f - 1]`` for frame f.
    """

    name: str
    path: Path
    scenario: str
    fps: float
    camera_wearer: int
    people: list[dict]
    pairs: list[PairRecord]

    def boxes(self, view: str, *, full: bool = False) -> dict[int, FrameBoxes]:
        """The view's boxes as ``{frame: FrameBoxes}`` (visible boxes, or full ones)."""
        if view not in VIEWS:
            raise ValueError(f"view must be one of {', '.join(VIEWS)}, got {view!r}")
        out = {}
        for pair in self.pairs:
            labels = getattr(pair, view).labels
            out[pair.frame] = FrameBoxes(
                pair.frame, labels.ids, labels.full_boxes if full else labels.boxes
            )
        return out

    def visibility(self, view: str) -> dict[int, np.ndarray]:
        """Visible fractions aligned with :meth:`boxes`: ``{frame: (N,) array}``."""
        if view not in VIEWS:
            raise ValueError(f"view must be one of {', '.join(VIEWS)}, got {view!r}")
        return {pair.frame: getattr(pair, view).labels.visible for pair in self.pairs}


def _parse_labels(doc: _Doc) -> ViewLabels:
    rows = doc.items()
    n = len(rows)
    ids = np.empty(n, np.int64)
    boxes, full = np.empty((n, 4)), np.empty((n, 4))
    visible, truncated = np.empty(n), np.empty(n, bool)
    pixels = np.empty(n, np.int64)
    ground, head = np.empty((n, 3)), np.empty((n, 3))
    for k, row in enumerate(rows):
        ids[k] = row["id"].int(0)
        boxes[k] = row["box"].numbers((4,))
        full[k] = row["full_box"].numbers((4,))
        if (boxes[k, 2:] <= 0).any():
            raise row["box"].error(f"width and height must be > 0, got {boxes[k].tolist()}")
        visible[k] = row["visible"].number(0.0, 1.0)
        truncated[k] = row["truncated"].bool()
        pixels[k] = row["visible_pixels"].int(1)
        ground[k] = row["ground"].numbers((3,))
        head[k] = row["head"].numbers((3,))
    if np.unique(ids).size != n:
        raise doc.error(f"repeated person id in {sorted(ids.tolist())}")
    return ViewLabels(ids, boxes, full, visible, truncated, pixels, ground, head)


def _parse_camera(doc: _Doc) -> Camera:
    d = doc.value
    if not isinstance(d, dict):
        raise doc.error("expected a camera object with K, R, c, width, height")
    K, R, c = doc["K"].numbers((3, 3)), doc["R"].numbers((3, 3)), doc["c"].numbers((3,))
    width, height = doc["width"].int(1), doc["height"].int(1)
    try:
        return Camera(K=K, R=R, c=c, width=width, height=height)
    except ValueError as exc:
        raise doc.error(str(exc)) from None


def read_scene(path: str | os.PathLike, root: str | os.PathLike | None = None) -> SceneRecord:
    """Read and validate one scene annotation file.

    Args:
        path: ``ROOT/annotations/SCENE.json``.
        root: the dataset folder image paths are relative to (default: the file's grandparent).

    Returns:
        The :class:`SceneRecord`.

    Raises:
        SchemaError: the file is missing, not JSON, or does not follow the schema; the message
            names the file and the field, e.g. ``s00001.json: frames[3].ego.people[0].box:
            expected numbers of shape (4,), got shape (3,)``.
    """
    path = Path(path)
    root = path.resolve().parent.parent if root is None else Path(root)
    doc = _Doc(_load_json(path), os.fspath(path))
    _check_header(doc, SCHEMA_NAME)
    name = doc["scene"].str()
    scenario = doc["scenario"].str()
    wearer = doc["camera_wearer"].int(0)
    fps = doc["fps"].number(1e-9)
    people = [p.value for p in doc["people"].items()]
    for p in doc["people"].items():
        p["id"].int(0)
        p["height"].number(0.1, 3.0)
    frames = doc["frames"].items()
    if len(frames) != doc["n_frames"].int(1):
        raise doc["frames"].error(
            f"holds {len(frames)} frames but n_frames is {doc.value['n_frames']}"
        )
    pairs = []
    for k, fr in enumerate(frames):
        frame = fr["frame"].int(1)
        if frame != k + 1:
            raise fr["frame"].error(f"expected frame {k + 1} (frames are 1..F in order)")
        views = {}
        for view in VIEWS:
            v = fr[view]
            views[view] = ViewRecord(
                view=view,
                image_path=root / v["image"].str(),
                camera=_parse_camera(v["camera"]),
                labels=_parse_labels(v["people"]),
            )
        pairs.append(PairRecord(scene=name, frame=frame, scenario=scenario,
                                camera_wearer=wearer, top=views["top"], ego=views["ego"]))
    return SceneRecord(name=name, path=path, scenario=scenario, fps=fps, camera_wearer=wearer,
                       people=people, pairs=pairs)


class SyntheticDataset:
    """A rendered dataset folder: its manifest, scenes and labelled pairs.

    Scenes are parsed lazily and cached one at a time, so iterating over a large dataset holds
    one scene's labels in memory.

    Args:
        root: the dataset folder (holding ``dataset.json``).

    Raises:
        SchemaError: missing or malformed manifest.
    """

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        path = self.root / MANIFEST
        doc = _Doc(_load_json(path), os.fspath(path))
        _check_header(doc, SCHEMA_NAME + ".dataset")
        self.scenario = doc["scenario"].str()
        self.seed = doc["seed"].int()
        self.manifest = doc.value
        self._entries = []
        for entry in doc["scenes"].items():
            self._entries.append(
                (entry["name"].str(), entry["annotation"].str(), entry["n_frames"].int(1))
            )
        self._cache: tuple[str, SceneRecord] | None = None

    @property
    def scene_names(self) -> list[str]:
        """Names of the scenes, in order."""
        return [e[0] for e in self._entries]

    def __len__(self) -> int:
        """Number of labelled pairs."""
        return sum(e[2] for e in self._entries)

    def content_sha256(self) -> str:
        """SHA-256 of the dataset's content: the manifest, every scene's annotation file and
        every image under ``images/``, each with its path relative to the folder.

        It keys results computed from the data (the ablation's cells): a folder re-rendered at
        the same path gets another key, and a copied or moved folder keeps its key.

        Raises:
            OSError: a file cannot be read.
            InputFileError: a manifest or annotation that is not a regular file (a FIFO, a
                device), refused before it is read.
        """
        files = [MANIFEST, *(annotation for _, annotation, _ in self._entries)]
        images = self.root / "images"
        if images.is_dir():
            files += sorted(p.relative_to(self.root).as_posix() for p in images.rglob("*")
                            if p.is_file())
        digest = hashlib.sha256()
        for rel in files:
            path = self.root / rel
            digest.update(f"{rel}\0{path.stat().st_size}\0".encode())
            with open(check_input_file(path), "rb") as handle:
                while chunk := handle.read(1 << 20):
                    digest.update(chunk)
        return digest.hexdigest()

    def scene(self, name: str) -> SceneRecord:
        """The parsed scene ``name``."""
        if self._cache is not None and self._cache[0] == name:
            return self._cache[1]
        for entry_name, annotation, _ in self._entries:
            if entry_name == name:
                record = read_scene(self.root / annotation, self.root)
                self._cache = (name, record)
                return record
        raise KeyError(f"{os.fspath(self.root)}: no scene {name!r}")

    def scenes(self) -> Iterator[SceneRecord]:
        """Every scene, in order."""
        for name in self.scene_names:
            yield self.scene(name)

    def pairs(self) -> Iterator[PairRecord]:
        """Every labelled pair, scene by scene, frame by frame."""
        for record in self.scenes():
            yield from record.pairs

    def __iter__(self) -> Iterator[PairRecord]:
        return self.pairs()


def resolve_pair(spec: str, scene: str | None = None, frame: int | None = None
                 ) -> tuple[Path, Path, int]:
    """The (scene file, dataset root, frame) a pair's name designates, as ``xvmatch show``
    reads it: a dataset folder (and ``scene``, default the first), a scene file
    (``annotations/SCENE.json``), or an image (``images/top|ego/SCENE_FRAME.jpg``, whose frame
    is the default).

    Raises:
        ValueError: a path that is none of these, or a scene the dataset does not hold.
    """
    path = Path(spec)
    if path.is_dir():
        if not (path / MANIFEST).is_file():
            raise ValueError(f"{spec}: folder has no {MANIFEST}; is it an xvmatch synth output?")
        names = SyntheticDataset(path).scene_names
        name = scene or (names[0] if names else None)
        if name not in names:
            raise ValueError(f"{spec}: no scene {name!r} (have {', '.join(names[:5])}...)")
        return path / "annotations" / f"{name}.json", path, frame or 1
    if not path.is_file():
        raise ValueError(f"{spec}: no such file or folder")
    if path.suffix == ".json":
        return path, path.resolve().parent.parent, frame or 1
    stem = path.stem
    if path.parent.name not in ("top", "ego") or "_" not in stem:
        raise ValueError(f"{spec}: expected ROOT/images/top|ego/SCENE_FRAME.jpg")
    name, _, number = stem.rpartition("_")
    if not number.isdigit():
        raise ValueError(f"{spec}: file name must end in _FRAME (digits), got {path.name!r}")
    root = path.resolve().parent.parent.parent
    return root / "annotations" / f"{name}.json", root, frame or int(number)


def person_crops(
    image: np.ndarray,
    labels: ViewLabels,
    *,
    size: tuple[int, int] = (64, 128),
    min_visible: float = 0.0,
    min_pixels: int = 1,
    context: float = 0.1,
    full: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Crops of the labelled people, resized to one size: the appearance branch's input.

    The crop is the (visible, or ``full``) box cut by :func:`~xvmatch.formats.crops.box_crops`.

    Args:
        image: ``(H, W, 3)`` uint8 image of the view.
        labels: the view's labels.
        size: (width, height) of the crops.
        min_visible: leave out people whose visible fraction is below this.
        min_pixels: leave out people with fewer visible pixels.
        context: relative margin around the box.
        full: crop the full (unoccluded) box instead of the visible one.

    Returns:
        (ids, crops): ``(M,)`` ids and ``(M, size[1], size[0], 3)`` uint8 crops.
    """
    keep = (labels.visible >= min_visible) & (labels.visible_pixels >= min_pixels)
    boxes = (labels.full_boxes if full else labels.boxes)[keep]
    return labels.ids[keep], box_crops(image, boxes, size, context)


@dataclass(frozen=True)
class SceneInputs:
    """A synthetic scene laid out as a user's data: what ``xvmatch associate`` reads.

    Attributes:
        top: MOT box file of the top view (ground-truth ids, for ``xvmatch evaluate``).
        hor: MOT box file of the egocentric view.
        cameras: folder of per-frame camera files (``000001.json``: cameras ``top``, ``ego``).
        top_images: glob pattern of the scene's top images (``--top-images``).
        hor_images: glob pattern of the scene's egocentric images (``--hor-images``).
    """

    top: Path
    hor: Path
    cameras: Path
    top_images: str
    hor_images: str


def write_scene_inputs(scene: SceneRecord, out: str | os.PathLike) -> SceneInputs:
    """Write a scene's boxes and cameras as a user would have them (MOT files, camera files);
    the images stay where they are, named by a glob pattern. Files are written atomically.

    Args:
        scene: a scene of a dataset written by :func:`generate_dataset`.
        out: folder to write ``top.txt``, ``hor.txt`` and ``cameras/`` into.
    """
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.formats.mot_boxes import write_mot_boxes

    out = Path(out)
    (out / "cameras").mkdir(parents=True, exist_ok=True)
    write_mot_boxes(out / "top.txt", scene.boxes("top"))
    write_mot_boxes(out / "hor.txt", scene.boxes("ego"))
    for pair in scene.pairs:
        save_cameras(out / "cameras" / f"{pair.frame:06d}.json",
                     {"top": pair.top.camera, "ego": pair.ego.camera})
    first = scene.pairs[0]
    return SceneInputs(
        top=out / "top.txt",
        hor=out / "hor.txt",
        cameras=out / "cameras",
        top_images=os.fspath(first.top.image_path.parent / f"{scene.name}_*.jpg"),
        hor_images=os.fspath(first.ego.image_path.parent / f"{scene.name}_*.jpg"),
    )


# --------------------------------------------------------------------------------------------
# Pictures


def _id_colour(pid: int) -> tuple[int, int, int]:
    """A distinct, stable BGR colour per id (golden-angle hues)."""
    import cv2

    hue = int((pid * 137.508) % 180)
    bgr = cv2.cvtColor(np.array([[[hue, 220, 255]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0]
    return int(bgr[0]), int(bgr[1]), int(bgr[2])


def draw_pair(
    pair: PairRecord,
    images: Sequence[np.ndarray] | None = None,
    *,
    full_boxes: bool = False,
    title: bool = True,
) -> np.ndarray:
    """Both views side by side, each person's box and id in a colour shared across views.

    The camera wearer's top-view box is labelled ``O`` (the camera location). Views of unequal
    heights are scaled to the top view's height.

    Args:
        pair: the labelled pair.
        images: the (top, ego) images; read from disk when ``None``.
        full_boxes: also draw the full (unoccluded) boxes, thin.
        title: add a caption strip with scene, frame and scenario.

    Returns:
        ``(H, W_top + W_ego, 3)`` uint8 BGR picture (plus the caption strip).
    """
    import cv2

    if images is None:
        images = (pair.top.load_image(), pair.ego.load_image())
    panels = []
    target_h = images[0].shape[0]
    for view_rec, image in zip((pair.top, pair.ego), images, strict=True):
        img = image.copy()
        lab = view_rec.labels
        scale = max(img.shape[0] / 360.0, 0.6)
        for k in range(len(lab)):
            pid = int(lab.ids[k])
            colour = _id_colour(pid)
            if full_boxes:
                x, y, w, h = lab.full_boxes[k]
                cv2.rectangle(img, (round(x * 16), round(y * 16)),
                              (round((x + w) * 16), round((y + h) * 16)), colour, 1,
                              cv2.LINE_AA, 4)
            x, y, w, h = lab.boxes[k]
            cv2.rectangle(img, (int(x), int(y)), (int(x + w) - 1, int(y + h) - 1), colour,
                          1 if w < 20 else 2)
            text = f"O:{pid}" if view_rec.view == "top" and pid == pair.camera_wearer else str(pid)
            org = (int(x), max(int(y) - 3, 10))
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale, (0, 0, 0), 3,
                        cv2.LINE_AA)
            cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, 0.4 * scale, colour, 1,
                        cv2.LINE_AA)
        if img.shape[0] != target_h:
            img = cv2.resize(img, (round(img.shape[1] * target_h / img.shape[0]), target_h),
                             interpolation=cv2.INTER_AREA)
        panels.append(img)
    picture = np.concatenate([panels[0], np.full((target_h, 4, 3), 255, np.uint8), panels[1]],
                             axis=1)
    if title:
        strip = np.full((22, picture.shape[1], 3), 32, np.uint8)
        top_name = "top (drone)" if pair.scenario == "drone" else "overview (building)"
        caption = (f"{pair.scene} frame {pair.frame}: {top_name} | egocentric; "
                   f"same colour = same person, O = camera wearer")
        cv2.putText(strip, caption, (6, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (235, 235, 235), 1,
                    cv2.LINE_AA)
        picture = np.concatenate([strip, picture], axis=0)
    return picture
