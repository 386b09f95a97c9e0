"""Named cameras read from and written to a JSON file.

File format (version 1)::

    {
      "version": 1,
      "cameras": {
        "top": {"K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],
                "R": [[...], [...], [...]],      # world -> camera rotation (Eq. 4)
                "c": [x, y, z],                  # camera centre, world units (metres)
                "width": 1920, "height": 1080},  # image size, pixels
        "ego": {...}
      }
    }

The convention is that of :class:`~xvmatch.geometry.camera.Camera` and Eq. 4 of the
geometric-priors paper, ``lambda [u, v, 1]^T = K R (X - c)``. Camera names are free strings;
the pipeline uses ``"top"`` (static overview camera) and ``"ego"`` (egocentric camera).
A camera may instead be ``{"H": [[...]], "width": W, "height": H}``, an image -> ground
homography (:func:`load_ground_cameras` only, for ``xvmatch multicam``).
Unknown keys are rejected so that a typo (``"k"`` for ``"K"``) cannot go unnoticed.
A file ``xvmatch calibrate`` wrote also has ``"estimated": {name: record}`` (:data:`ESTIMATED`):
its cameras are each in their own view's ground frame, so the commands that need cameras in one
world refuse it by name; :func:`load_estimated` reads it. Records whose ``world`` is
:data:`REGISTERED` (``xvmatch multicam`` without ``--cameras``) are in one world and read as any.

Every camera is checked for physical sense as it is read
(:func:`~xvmatch.geometry.camera.check_camera_sense`: focal lengths > 0, a proper rotation, a
centre within 100 km and above the ground z = 0, some ground in the image; the camera named
:data:`TOP_CAMERA` must also look down), and an ``H`` camera, or the homography of a ``K, R, c``
camera in :func:`load_ground_cameras`, must see the ground along the bottom edge of its image
(:func:`~xvmatch.geometry.ground_plane.check_ground_view`). The file is opened with
:func:`~xvmatch.core.input_files.read_input_text`, so a FIFO or a device is refused at once.

Every error is a :class:`CameraFileError` whose message starts with the file and the field,
e.g. ``cams.json: cameras.ego.K: expected 3x3 numbers`` or
``cams/top.json: cameras.top.K: focal length fx = -800 must be > 0``.
"""

from __future__ import annotations

import errno
import json
import math
import os
import tempfile
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from xvmatch.core.input_files import InputFileError, read_input_text
from xvmatch.core.json_text import parse_json
from xvmatch.geometry.camera import Camera, CameraSenseError, check_camera_sense
from xvmatch.geometry.ground_plane import GroundCamera, check_ground_view

__all__ = ["ESTIMATED", "FORMAT_VERSION", "REGISTERED", "TOP_CAMERA", "CameraFileError",
           "load_cameras", "load_estimated", "load_ground_cameras", "save_cameras"]

FORMAT_VERSION = 1
TOP_CAMERA = "top"
"""Name of the top (overview, drone) camera in the files of ``associate`` and ``track``: the
one camera that must look down."""
_CAMERA_FIELDS = ("K", "R", "c", "width", "height")
_H_FIELDS = ("H", "width", "height")
_TOP_FIELDS = ("version", "cameras", "estimated")
ESTIMATED = "estimated"
"""Top-level field of a file ``xvmatch calibrate`` wrote: ``{camera name: how it was
estimated}``. Its cameras were each calibrated from the people in their own view, in that
view's own ground frame (above the origin, looking along +x): they are not in one world."""
REGISTERED = "registered from people"
"""The ``world`` of every ``estimated`` record of a file ``xvmatch multicam`` wrote without a
calibration: its cameras were calibrated from their people *and* registered to one another,
so they are in one world (that of the camera named ``reference``) and every command reads
them."""


class CameraFileError(ValueError):
    """A camera file is unreadable or a field in it is invalid; the message names both."""


def _is_number(x: Any) -> bool:
    """A finite JSON number (bools are ints in Python but not numbers here)."""
    if isinstance(x, bool) or not isinstance(x, int | float):
        return False
    try:
        return math.isfinite(x)
    except OverflowError:  # an integer too large for a float
        return False


def _matrix(value: Any, rows: int, cols: int, where: str) -> np.ndarray:
    shape = f"{rows}x{cols}" if cols else f"{rows}"
    ok = isinstance(value, list) and len(value) == rows
    if ok and cols:
        ok = all(isinstance(r, list) and len(r) == cols and all(map(_is_number, r)) for r in value)
    elif ok:
        ok = all(map(_is_number, value))
    if not ok:
        raise CameraFileError(f"{where}: expected {shape} numbers (finite), got {value!r:.80}")
    return np.asarray(value, dtype=float)


def _size(value: Any, where: str) -> int:
    if not _is_number(value) or value <= 0 or value != int(value):
        raise CameraFileError(f"{where}: expected a positive integer (pixels), got {value!r}")
    return int(value)


def _camera(record: Any, where: str, top: bool = False) -> Camera:
    """A ``K, R, c`` record as a Camera that makes physical sense (``top``: it looks down)."""
    if isinstance(record, dict) and "H" in record:
        raise CameraFileError(f"{where}: a homography camera (H); this command needs K, R, c "
                              "(only multicam reads H cameras)")
    if not isinstance(record, dict):
        raise CameraFileError(f"{where}: expected an object with {', '.join(_CAMERA_FIELDS)}")
    unknown = sorted(set(record) - set(_CAMERA_FIELDS))
    if unknown:
        raise CameraFileError(
            f"{where}: unknown field(s) {', '.join(unknown)} (expected {', '.join(_CAMERA_FIELDS)})"
        )
    missing = [k for k in _CAMERA_FIELDS if k not in record]
    if missing:
        raise CameraFileError(f"{where}: missing field(s) {', '.join(missing)}")
    K = _matrix(record["K"], 3, 3, f"{where}.K")
    if abs(np.linalg.det(K)) < 1e-12:
        raise CameraFileError(f"{where}.K: singular intrinsic matrix (det = 0); check fx, fy")
    R = _matrix(record["R"], 3, 3, f"{where}.R")
    c = _matrix(record["c"], 3, 0, f"{where}.c")
    width = _size(record["width"], f"{where}.width")
    height = _size(record["height"], f"{where}.height")
    try:
        check_camera_sense(K, R, c, width, height, top=top)
    except CameraSenseError as exc:
        raise CameraFileError(f"{where}.{exc.field}: {exc.reason}") from None
    return Camera(K=K, R=R, c=c, width=width, height=height)


def _ground_view(ground: GroundCamera, where: str) -> GroundCamera:
    """``ground`` if its image sees the ground along its bottom edge; CameraFileError if not."""
    try:
        check_ground_view(ground.H, ground.width, ground.height)
    except ValueError as exc:
        raise CameraFileError(f"{where}: {exc}") from None
    return ground


def _ground_camera(record: Any, where: str, top: bool = False) -> GroundCamera:
    """A camera record of either form (``K, R, c`` or ``H``) as a :class:`GroundCamera`
    (``top`` is not used: the static cameras of multicam have no top camera)."""
    if not (isinstance(record, dict) and "H" in record):
        cam = _camera(record, where)
        try:
            ground = GroundCamera.from_camera(cam)
        except ValueError as exc:
            raise CameraFileError(f"{where}: {exc}") from None
        return _ground_view(ground, where)
    unknown = sorted(set(record) - set(_H_FIELDS))
    if unknown:
        raise CameraFileError(f"{where}: unknown field(s) {', '.join(unknown)} (a homography "
                              f"camera has {', '.join(_H_FIELDS)}; K, R, c go without H)")
    missing = [k for k in _H_FIELDS if k not in record]
    if missing:
        raise CameraFileError(f"{where}: missing field(s) {', '.join(missing)}")
    H = _matrix(record["H"], 3, 3, f"{where}.H")
    width = _size(record["width"], f"{where}.width")
    height = _size(record["height"], f"{where}.height")
    try:
        ground = GroundCamera(H, width, height)
    except ValueError as exc:
        raise CameraFileError(f"{where}.H: {exc}") from None
    return _ground_view(ground, f"{where}.H")


def load_ground_cameras(path: str | os.PathLike[str]) -> dict[str, GroundCamera]:
    """Read named static cameras of either form for the ground plane (``xvmatch multicam``).

    A camera is ``K, R, c, width, height`` as in :func:`load_cameras`, or ``H, width, height``
    with ``H`` the image -> ground homography (``[X, Y, 1]^T ~ H [u, v, 1]^T``, metres,
    ground z = 0; :mod:`xvmatch.geometry.ground_plane`). Version 1, the same file otherwise.
    Each camera must see the ground along the bottom edge of its image; no camera is held to
    look down (none is the top camera).

    Returns:
        ``{name: GroundCamera}`` in file order.

    Raises:
        FileNotFoundError: the file does not exist.
        CameraFileError: as :func:`load_cameras`; a singular or non-finite ``H``, or an image
            whose bottom edge sees no ground in front, too.
    """
    return _load(path, _ground_camera, (), top=None)


def load_estimated(path: str | os.PathLike[str]) -> tuple[dict[str, Camera], dict[str, dict]]:
    """Read a file ``xvmatch calibrate`` wrote: its cameras, each in its own view's ground
    frame, and the ``estimated`` record of each (:data:`ESTIMATED`).

    Raises:
        CameraFileError: as :func:`load_cameras`; a file without ``estimated`` too.
    """
    found: dict[str, dict] = {}
    cameras = _load(path, _camera, (), top=TOP_CAMERA, estimated=found)
    if not found:
        raise CameraFileError(f"{os.fspath(path)}: {ESTIMATED}: missing; this is not a file "
                              "written by xvmatch calibrate")
    return cameras, found


def load_cameras(
    path: str | os.PathLike[str], *, required: Iterable[str] = ()
) -> dict[str, Camera]:
    """Read named cameras from a version-1 camera file (format in the module docstring).

    Args:
        path: the JSON file.
        required: camera names that must be present, e.g. ``("top", "ego")``.

    Returns:
        ``{name: Camera}`` in file order.

    Every camera must make physical sense
    (:func:`~xvmatch.geometry.camera.check_camera_sense`); the one named :data:`TOP_CAMERA`
    must also look down.

    Raises:
        FileNotFoundError: the file does not exist.
        CameraFileError: not a regular file (a FIFO, a device), invalid JSON, wrong version, an
            invalid field, or a camera that makes no physical sense; the message is
            ``"<file>: <field path>: <problem>"``.
    """
    return _load(path, _camera, required, top=TOP_CAMERA)


def _read_text(name: str) -> str:
    """The file's text, read without blocking (a FIFO or a device refused at once)."""
    try:
        return read_input_text(name)
    except InputFileError as exc:
        if not os.path.lexists(name):
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", name) from None
        raise CameraFileError(str(exc)) from None


def _load(path: str | os.PathLike[str], parse: Any, required: Iterable[str],
          top: str | None, estimated: dict | None = None) -> dict:
    """The version-1 file with each camera record read by ``parse(record, where, is_top)``,
    ``is_top`` true for the camera named ``top``. A file with an ``estimated`` record is
    refused unless ``estimated`` is a dict, which then receives it."""
    name = os.fspath(path)
    text = _read_text(name)
    data = parse_json(text, name, CameraFileError)  # syntax, nesting depth: one line
    try:
        if not isinstance(data, dict):
            raise CameraFileError('expected a JSON object {"version": 1, "cameras": {...}}')
        unknown = sorted(set(data) - set(_TOP_FIELDS))
        if unknown:
            raise CameraFileError(
                f"unknown top-level field(s) {', '.join(unknown)} (expected version, cameras; "
                f"{ESTIMATED} in a file xvmatch calibrate wrote)"
            )
        if "version" not in data:
            raise CameraFileError(f'version: missing; add "version": {FORMAT_VERSION}')
        if isinstance(data["version"], bool) or data["version"] != FORMAT_VERSION:
            raise CameraFileError(
                f"version: unsupported {data['version']!r}, this reader knows {FORMAT_VERSION}"
            )
        cams = data.get("cameras")
        if not isinstance(cams, dict) or not cams:
            raise CameraFileError("cameras: expected a non-empty object {name: camera}")
        cameras = {str(key): parse(rec, f"cameras.{key}", key == top)
                   for key, rec in cams.items()}
        _check_estimated(data.get(ESTIMATED), cameras, estimated)
        missing = [k for k in required if k not in cameras]
        if missing:
            raise CameraFileError(
                f"cameras: missing required camera(s) {', '.join(missing)}; "
                f"the file has {', '.join(cameras)}"
            )
    except CameraFileError as exc:
        raise CameraFileError(f"{name}: {exc}") from None
    return cameras


def _check_estimated(record: Any, cameras: Mapping[str, Any], into: dict | None) -> None:
    """The ``estimated`` record: absent, or ``{camera name: object}`` over the file's cameras;
    refused where the caller needs cameras in one world (``into`` None)."""
    if record is None:
        return
    if not isinstance(record, dict) or not record or not all(
            isinstance(v, dict) for v in record.values()):
        raise CameraFileError(f"{ESTIMATED}: expected an object {{camera name: record}}")
    unknown = [k for k in record if k not in cameras]
    if unknown:
        raise CameraFileError(f"{ESTIMATED}: names camera(s) not in the file: "
                              f"{', '.join(map(str, unknown))}")
    if into is None and all(v.get("world") == REGISTERED for v in record.values()):
        return  # registered into one world (xvmatch multicam without --cameras)
    if into is None:
        raise CameraFileError(
            f"{ESTIMATED}: these cameras were calibrated one view at a time from the people in "
            "each (xvmatch calibrate), each in its own ground frame, not in one world; this "
            "command needs cameras in one world (a calibration of the site)")
    into.update(record)


def save_cameras(path: str | os.PathLike[str],
                 cameras: Mapping[str, Camera | GroundCamera],
                 estimated: Mapping[str, dict] | None = None) -> None:
    """Write named cameras to a version-1 camera file, atomically.

    The JSON is written to a temporary file in the destination directory, flushed to disk and
    moved over ``path`` with ``os.replace``, so readers see either the old or the new file,
    never a partial one. Floats are written with full precision, so a round trip is exact.

    Args:
        path: destination file; its directory must exist.
        cameras: ``{name: Camera}``, at least one, names non-empty strings; a
            :class:`GroundCamera` is written as its ``Camera`` when it has one, else as ``H``.
        estimated: ``{name: record}`` of cameras estimated one view at a time
            (:data:`ESTIMATED`; ``xvmatch calibrate``), JSON-ready, or None.

    Raises:
        CameraFileError: no cameras, a bad name, or a value that is not a Camera.
        FileNotFoundError: the destination directory does not exist.
    """
    name = os.fspath(path)
    if not isinstance(cameras, Mapping) or not cameras:
        raise CameraFileError(f"{name}: cameras: expected a non-empty mapping {{name: Camera}}")
    records = {}
    for key, cam in cameras.items():
        if not isinstance(key, str) or not key:
            raise CameraFileError(f"{name}: cameras: names must be non-empty strings, got {key!r}")
        if isinstance(cam, GroundCamera):  # an H camera, or the Camera it was made from
            if cam.camera is None:
                records[key] = {"H": cam.H.tolist(), "width": cam.width, "height": cam.height}
                continue
            cam = cam.camera
        if not isinstance(cam, Camera):
            raise CameraFileError(f"{name}: cameras.{key}: expected a Camera, got {type(cam)}")
        for field in ("K", "R", "c"):
            if not np.isfinite(getattr(cam, field)).all():
                raise CameraFileError(f"{name}: cameras.{key}.{field}: contains NaN or inf")
        records[key] = cam.to_dict()
    doc: dict[str, Any] = {"version": FORMAT_VERSION, "cameras": records}
    if estimated:
        unknown = [k for k in estimated if k not in records]
        if unknown:
            raise CameraFileError(f"{name}: {ESTIMATED}: names camera(s) not written: "
                                  f"{', '.join(map(str, unknown))}")
        doc[ESTIMATED] = dict(estimated)
    text = json.dumps(doc, indent=2, allow_nan=False)

    directory = os.path.dirname(os.path.abspath(name))
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"{name}: directory {directory} does not exist")
    mode = os.stat(name).st_mode & 0o777 if os.path.exists(name) else 0o644
    fd, tmp = tempfile.mkstemp(prefix=".", suffix=".tmp", dir=directory)
    try:
        os.chmod(tmp, mode)  # mkstemp creates 0600; keep the usual permissions of a data file
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, name)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
