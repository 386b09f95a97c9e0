"""Every record the tool reads back is checked field by field (issue 65): a site bundle's
``adaptation.npz`` (truncated, not a zip, a zip bomb, a fractional rank), ``--precision`` where
no appearance network runs, a ``--ckpt_path`` that is crafted, truncated or a FIFO, an
``offset.json`` out of ``--offset``'s range, and a ``--clip-start`` beyond the video. Each is one
line through the command line (exit 2, no traceback) and a ``ValueError`` through the library."""

from __future__ import annotations

import hashlib
import io
import json
import os
import struct
import subprocess
import sys
import threading
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene
from xvmatch.inference.adaptation.site_adaptation import (
    ADAPTATION_FILE,
    NPY_HEADER_BYTES,
    SiteAdaptation,
    adaptation_array_bytes,
    adaptation_bytes,
    load_adaptation,
)
from xvmatch.inference.matching.bundle import DEFAULT_BUNDLE, MANIFEST, BundleError, load_bundle

REPO = Path(__file__).resolve().parents[1]
DIM = 16
PROMPT_S = 60.0
"""Most seconds a refusal of a FIFO may take (a hang fails the test instead of blocking it)."""


def _cli(capsys, *argv: str) -> tuple[int, str]:
    """Exit code and stderr of ``xvmatch ARGV``."""
    capsys.readouterr()
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def _one_line(code: int, err: str, *words: str) -> str:
    """The single error line of a refused run, checked to name ``words``."""
    assert code == 2, err
    assert err.count("\n") == 1 and err.startswith("xvmatch: error: "), err
    assert "Traceback" not in err
    for word in words:
        assert word in err, (word, err)
    return err


def _promptly(call: Callable[[], object], fifo: Path) -> BaseException | None:
    """Run ``call`` in a thread; the exception it raised (None if none). A call still blocked
    after :data:`PROMPT_S` fails the test, after opening ``fifo`` for writing to release it."""
    outcome: list[BaseException | None] = []

    def run() -> None:
        try:
            call()
            outcome.append(None)
        except BaseException as exc:  # handed back to the test
            outcome.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    thread.join(PROMPT_S)
    if thread.is_alive():
        fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        pytest.fail(f"blocked on the FIFO {fifo} for {PROMPT_S} s")
    return outcome[0]


# --------------------------------------------------------------------------------------------
# adaptation.npz


def _arrays(rank: int = 0, dim: int = DIM) -> dict[str, np.ndarray]:
    """The arrays of a valid adaptation (the identity map, or rank ``rank``)."""
    adaptation = SiteAdaptation.identity(dim)
    arrays = adaptation.arrays()
    if rank:
        arrays["projection"] = np.eye(dim)[:, :rank]
        arrays["rank"] = np.array(rank)
    return arrays


def _npz(arrays: dict[str, np.ndarray], compression: int = zipfile.ZIP_STORED) -> bytes:
    """An ``.npz`` of ``arrays`` (``np.savez``'s layout, with the given compression)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as archive:
        for key, value in arrays.items():
            member = io.BytesIO()
            np.save(member, value, allow_pickle=True)
            archive.writestr(f"{key}.npy", member.getvalue())
    return buf.getvalue()


def _bomb(dim: int = DIM, inflated: int = 64 << 20) -> bytes:
    """A valid adaptation whose projection member inflates to ``inflated`` bytes of zeros: a
    real, highly compressible member, small on disk (about a thousandth of its size)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as archive:
        for key, value in _arrays(dim=dim).items():
            if key == "projection":
                continue
            member = io.BytesIO()
            np.save(member, value)
            archive.writestr(f"{key}.npy", member.getvalue())
        cols = inflated // (8 * dim)
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f8", "fortran_order": False,
                                                      "shape": (dim, cols)})
        with archive.open("projection.npy", "w", force_zip64=True) as member:
            member.write(header.getvalue())
            block = bytes(1 << 20)
            for _ in range(dim * cols * 8 // len(block)):
                member.write(block)
    return buf.getvalue()


def _declared(data: bytes, name: str, size: int) -> bytes:
    """``data`` (a zip) with member ``name``'s uncompressed size in the central directory set
    to ``size``: a small member that declares a huge one."""
    out = bytearray(data)
    at = out.find(b"PK\x01\x02")
    while at >= 0:
        length = struct.unpack_from("<H", out, at + 28)[0]
        if out[at + 46:at + 46 + length] == name.encode():
            struct.pack_into("<I", out, at + 24, size)
            return bytes(out)
        at = out.find(b"PK\x01\x02", at + 4)
    raise AssertionError(f"no member {name}")


def _load(path: Path, dim: int = DIM):
    return load_adaptation(path, {"descriptors": dim}.get)


def _good() -> bytes:
    return _npz(_arrays(rank=4))


CORRUPT: dict[str, tuple[Callable[[], bytes], str]] = {
    "truncated": (lambda: _good()[: len(_good()) // 2], "not a readable adaptation file"),
    "truncated at the end": (lambda: _good()[:-30], "not a readable adaptation file"),
    "not a zip": (lambda: b"PK\x03\x04 not a zip at all", "not a readable adaptation file"),
    "text": (lambda: b"hello", "not a readable adaptation file"),
    "empty": (lambda: b"", "not a readable adaptation file"),
    "bad CRC": (lambda: _good().replace(np.eye(DIM)[:, :4].tobytes()[:64],
                                        b"\x01" * 64, 1), "array 'projection' is unreadable"),
    "zip bomb": (_bomb, "array 'projection' declares 67,108,992 bytes, more than the"),
    "declared 1.6 GB": (lambda: _declared(_good(), "projection.npy", 1_600_000_000),
                        "array 'projection' declares 1,600,000,000 bytes"),
    "fractional rank": (lambda: _npz({**_arrays(rank=4), "rank": np.array(4.5)}),
                        "array 'rank' must be an integer, got 4.5"),
    "whole float rank": (lambda: _npz({**_arrays(rank=4), "rank": np.array(4.0)}),
                         "array 'rank' must be an integer, got 4.0"),
    "bool rank": (lambda: _npz({**_arrays(), "rank": np.array(False)}),
                  "array 'rank' must be an integer"),
    "rank above D": (lambda: _npz({**_arrays(), "rank": np.array(DIM + 1)}),
                     f"array 'rank' must be in 0..{DIM}, got {DIM + 1}"),
    "negative rank": (lambda: _npz({**_arrays(), "rank": np.array(-1)}),
                      f"array 'rank' must be in 0..{DIM}, got -1"),
    "float version": (lambda: _npz({**_arrays(), "format_version": np.array(2.0)}),
                      "array 'format_version' must be an integer"),
    "pickled array": (lambda: _npz({**_arrays(), "top_mean": np.array([object()] * DIM)}),
                      "array 'top_mean' must hold plain numbers"),
    "long double": (lambda: _npz({**_arrays(), "top_mean": np.zeros(DIM, np.longdouble)}),
                    "array 'top_mean' must hold plain numbers of at most 8 bytes"),
    "tiny scale": (lambda: _npz({**_arrays(), "top_scale": np.full(DIM, 1e-300)}),
                   "array 'top_scale' must be > 0, at least 1e-06"),
    "missing rank": (lambda: _npz({k: v for k, v in _arrays().items() if k != "rank"}),
                     "array 'rank' is missing"),
}


@pytest.mark.parametrize("case", list(CORRUPT))
def test_a_bad_adaptation_file_is_one_line_naming_the_array(tmp_path, case) -> None:
    make, message = CORRUPT[case]
    path = tmp_path / ADAPTATION_FILE
    path.write_bytes(make())
    with pytest.raises(ValueError) as info:
        _load(path)
    assert message in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_a_header_that_lies_about_its_shape_is_refused_before_allocating(tmp_path) -> None:
    """A member within its bound whose ``.npy`` header claims a huge shape: refused on the
    header, not by allocating the array."""
    member = io.BytesIO()
    np.lib.format.write_array_header_1_0(member, {"descr": "<f8", "fortran_order": False,
                                                  "shape": (DIM, 10**12)})
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as archive:
        for key, value in _arrays().items():
            if key != "projection":
                archive.writestr(f"{key}.npy", _npy(value))
        archive.writestr("projection.npy", member.getvalue() + bytes(64))
    path = tmp_path / ADAPTATION_FILE
    path.write_bytes(buf.getvalue())
    with pytest.raises(ValueError, match=r"array 'projection': its header says \(16, "
                       r"1000000000000\) float64 .* truncated or corrupt"):
        _load(path)


def _npy(value: np.ndarray) -> bytes:
    member = io.BytesIO()
    np.save(member, value)
    return member.getvalue()


def test_the_bounds_are_the_largest_arrays_an_adaptation_holds(tmp_path) -> None:
    """The bound of each member is its largest shape at 8 bytes a number plus a header; the
    arrays adapt writes fit, at rank 0 (the full projection) and in a file of the largest
    vector."""
    bounds = adaptation_array_bytes(DIM)
    assert bounds["projection"] == DIM * DIM * 8 + NPY_HEADER_BYTES
    assert bounds["top_mean"] == DIM * 8 + NPY_HEADER_BYTES
    assert bounds["rank"] == 8 + NPY_HEADER_BYTES
    path = tmp_path / ADAPTATION_FILE
    for rank in (0, 4, DIM):
        path.write_bytes(adaptation_bytes(_load_via(rank)))
        back = _load(path)
        assert back.rank == rank and back.projection.shape == (DIM, DIM if rank == 0 else rank)
    # Deflated members (np.savez_compressed) are read too: only their inflated size counts.
    np.savez_compressed(path, **_arrays(rank=4))
    assert _load(path).rank == 4


def _load_via(rank: int) -> SiteAdaptation:
    a = _arrays(rank=rank)
    return SiteAdaptation(a["top_mean"], a["top_scale"], a["hor_mean"], a["hor_scale"],
                          a["projection"], a["calibration"], rank)


def test_a_file_larger_than_any_adaptation_is_refused_unread(tmp_path) -> None:
    path = tmp_path / ADAPTATION_FILE
    path.write_bytes(_good() + bytes(2 << 20))
    with pytest.raises(ValueError, match=r"not a readable adaptation file \(.*bytes, more "
                       r"than the"):
        _load(path)


def test_a_fifo_as_adaptation_file_is_refused_at_once(tmp_path) -> None:
    fifo = tmp_path / ADAPTATION_FILE
    os.mkfifo(fifo)
    exc = _promptly(lambda: _load(fifo), fifo)
    assert isinstance(exc, ValueError) and "is a FIFO" in str(exc), exc


def _site(tmp_path: Path, data: bytes, rank: int = 0) -> Path:
    """The shipped default's files (linked) plus ``data`` as its adaptation, recorded with
    its sha256 in the manifest (as a crafted bundle would be)."""
    folder = tmp_path / "site"
    folder.mkdir()
    for name in os.listdir(DEFAULT_BUNDLE):
        if name != MANIFEST:
            (folder / name).symlink_to(DEFAULT_BUNDLE / name)
    (folder / ADAPTATION_FILE).write_bytes(data)
    doc = json.loads((DEFAULT_BUNDLE / MANIFEST).read_text())
    doc["adaptation"] = {"file": ADAPTATION_FILE, "sha256": hashlib.sha256(data).hexdigest(),
                         "format_version": 2, "vector": "descriptors", "rank": rank,
                         "fitted_on": {}, "heldout": {}}
    (folder / MANIFEST).write_text(json.dumps(doc))
    return folder


@pytest.fixture(scope="module")
def boxes(tmp_path_factory) -> dict[str, Path]:
    """A 30-frame simulated box scene (top and horizontal box files)."""
    root = tmp_path_factory.mktemp("boxes")
    top, hor = write_box_scene(simulate_box_scene(n_frames=30, seed=1), root, "sim")
    return {"top": top, "hor": hor, "root": root}


def _default_dim() -> int:
    return json.loads((DEFAULT_BUNDLE / MANIFEST).read_text())["appearance"]["embedding_dim"]


BUNDLE_CASES = {
    "truncated": (lambda dim: adaptation_bytes(SiteAdaptation.identity(dim))[:500],
                  "not a readable adaptation file"),
    "not a zip": (lambda dim: b"PK\x03\x04 cut", "not a readable adaptation file"),
    "zip bomb": (lambda dim: _bomb(dim), "array 'projection' declares"),
    "fractional rank": (lambda dim: _npz({**_arrays(dim=dim), "rank": np.array(0.5)}),
                        "array 'rank' must be an integer, got 0.5"),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(BUNDLE_CASES))
def test_a_site_bundle_with_a_bad_adaptation_through_the_library_and_the_cli(
        tmp_path, boxes, capsys, case) -> None:
    """``associate --model SITE`` on boxes alone still opens the bundle's adaptation: one line
    naming the bundle's file and the array, exit 2."""
    make, message = BUNDLE_CASES[case]
    folder = _site(tmp_path, make(_default_dim()))
    with pytest.raises(BundleError) as info:
        load_bundle(folder)
    assert str(info.value).startswith(f"{folder / ADAPTATION_FILE}: ")
    assert message in str(info.value) and "\n" not in str(info.value)
    code, err = _cli(capsys, "associate", "--model", folder, "--top", boxes["top"], "--hor",
                     boxes["hor"], "--image-size", "2688x1512", "--out", tmp_path / "pred.csv")
    _one_line(code, err, str(folder / ADAPTATION_FILE), message)
    assert not (tmp_path / "pred.csv").exists()


@pytest.mark.slow
def test_an_adaptation_that_does_not_match_the_manifest_s_sha256_is_one_line(
        tmp_path, boxes, capsys) -> None:
    """The manifest's sha256 of ``adaptation.npz`` is checked before the file is read."""
    folder = _site(tmp_path, adaptation_bytes(SiteAdaptation.identity(_default_dim())))
    (folder / ADAPTATION_FILE).write_bytes(_bomb(_default_dim()))
    code, err = _cli(capsys, "associate", "--model", folder, "--top", boxes["top"], "--hor",
                     boxes["hor"], "--image-size", "2688x1512", "--out", tmp_path / "pred.csv")
    _one_line(code, err, str(folder / ADAPTATION_FILE), "does not match the manifest's")


@pytest.mark.slow
def test_a_valid_site_bundle_still_runs_on_boxes_alone(tmp_path, boxes, capsys) -> None:
    folder = _site(tmp_path, adaptation_bytes(SiteAdaptation.identity(_default_dim())))
    assert load_bundle(folder).adaptation.rank == 0
    code, err = _cli(capsys, "associate", "--model", folder, "--top", boxes["top"], "--hor",
                     boxes["hor"], "--image-size", "2688x1512", "--out", tmp_path / "pred.csv",
                     "--quiet")
    assert code == 0, err
    assert (tmp_path / "pred.csv").read_text()


# --------------------------------------------------------------------------------------------
# --precision where no appearance network runs


@pytest.mark.parametrize("precision", ["int8", "fp32"])
def test_precision_without_images_is_refused(tmp_path, boxes, capsys, precision) -> None:
    code, err = _cli(capsys, "associate", "--model", "default", "--precision", precision,
                     "--top", boxes["top"], "--hor", boxes["hor"], "--image-size", "2688x1512",
                     "--out", tmp_path / "pred.csv")
    _one_line(code, err, f"--precision {precision}", "--top-images and --hor-images")
    assert not (tmp_path / "pred.csv").exists()


def test_precision_on_a_box_only_bundle_is_refused(tmp_path, boxes, capsys, tiny_models) -> None:
    from xvmatch.commands._model import check_precision, open_models
    from xvmatch.commands._options import UsageError
    from xvmatch.inference.matching.bundle import BundleError

    bundle = tiny_models["boxes_bundle"]
    with pytest.raises(BundleError, match="precision 'int8' chooses the appearance network, "
                       "and this bundle has none"):
        open_models([str(bundle)], precision="int8")  # the library refuses it too
    models = open_models([str(bundle)])
    with pytest.raises(UsageError, match=r"--precision int8: --model .* has no appearance "
                       r"network \(a box-only matcher\)"):
        check_precision("int8", True, models, [str(bundle)])
    check_precision(None, False, models, [str(bundle)])  # not given: nothing to refuse
    code, err = _cli(capsys, "associate", "--model", bundle, "--precision", "int8",
                     "--top", boxes["top"], "--hor", boxes["hor"], "--image-size", "2688x1512",
                     "--out", tmp_path / "pred.csv")
    _one_line(code, err, "--precision int8")


# --------------------------------------------------------------------------------------------
# train / validate --ckpt_path


class _Marker:
    """Unpickled, creates a file: stands for code a crafted checkpoint would run."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


@pytest.fixture
def checkpoints(tmp_path) -> dict[str, Path]:
    """A weights-only Lightning-like checkpoint (``good``), one with pickled code
    (``crafted``, which would create ``marker``), a truncated one and a FIFO."""
    torch = pytest.importorskip("torch")
    pytest.importorskip("lightning")
    good = tmp_path / "good.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(3)}, "epoch": 0}, good)
    crafted = tmp_path / "crafted.ckpt"
    torch.save({"state_dict": {}, "payload": _Marker(tmp_path / "ran")}, crafted)
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(good.read_bytes()[:200])
    fifo = tmp_path / "fifo.ckpt"
    os.mkfifo(fifo)
    return {"good": good, "crafted": crafted, "truncated": truncated, "fifo": fifo,
            "marker": tmp_path / "ran", "nodict": _saved(torch, tmp_path, [1, 2])}


def _saved(torch, folder: Path, obj) -> Path:
    path = folder / "list.ckpt"
    torch.save(obj, path)
    return path


@pytest.mark.parametrize(("kind", "stage", "message"), [
    ("crafted", "fit", "not a checkpoint read as weights only (UnpicklingError: pickled "
     "objects other than tensors"),
    ("truncated", "fit", "not a checkpoint read as weights only"),
    ("crafted", "validate", "not a checkpoint read as weights only"),
    ("truncated", "validate", "not a checkpoint read as weights only"),
    ("nodict", "fit", "not a Lightning checkpoint (no state_dict)"),
])
@pytest.mark.slow
def test_a_bad_ckpt_path_is_one_line(checkpoints, tmp_path, capsys, monkeypatch, kind, stage,
                                     message) -> None:
    monkeypatch.chdir(tmp_path)
    code, err = _cli(capsys, "train", "--config", REPO / "configs" / "appearance_cpu.yaml",
                     "--stage", stage, "--ckpt_path", checkpoints[kind])
    _one_line(code, err, f"--ckpt_path {checkpoints[kind]}: ", message)
    assert "weights_only=False" not in err and "weights_only` set to `False" not in err
    assert not checkpoints["marker"].exists()


def test_the_ckpt_path_check_through_the_library(checkpoints) -> None:
    from jsonargparse import Namespace

    from xvmatch.training.train_cli import check_checkpoint_options, check_ckpt_path

    check_ckpt_path(str(checkpoints["good"]))
    check_ckpt_path("last")  # Lightning's own name for the run's last checkpoint
    for kind in ("crafted", "truncated", "nodict"):
        with pytest.raises(ValueError, match=rf"^--ckpt_path {checkpoints[kind]}: "):
            check_ckpt_path(str(checkpoints[kind]))
    with pytest.raises(ValueError, match="only a local checkpoint file"):
        check_ckpt_path("https://example.org/x.ckpt")
    exc = _promptly(lambda: check_ckpt_path(str(checkpoints["fifo"])), checkpoints["fifo"])
    assert isinstance(exc, ValueError) and "is a FIFO" in str(exc), exc
    assert not checkpoints["marker"].exists()
    config = Namespace(subcommand="fit", fit=Namespace(ckpt_path=None, weights_only=None))
    check_checkpoint_options(config)
    assert config.fit.weights_only is True  # Lightning is told to read weights only
    config.fit.weights_only = False
    with pytest.raises(ValueError, match="--weights_only false: checkpoints are read with "
                       "weights only"):
        check_checkpoint_options(config)


def test_weights_only_false_is_refused(tmp_path, capsys, monkeypatch) -> None:
    pytest.importorskip("lightning")
    monkeypatch.chdir(tmp_path)
    code, err = _cli(capsys, "train", "--config", REPO / "configs" / "appearance_cpu.yaml",
                     "--weights_only", "false")
    _one_line(code, err, "--weights_only false")


@pytest.mark.slow
@pytest.mark.parametrize("stage", ["fit", "validate"])
def test_a_fifo_ckpt_path_is_refused_at_once(checkpoints, tmp_path, stage) -> None:
    """Run in a subprocess with a time limit: a hang fails, never blocks the test run."""
    argv = [sys.executable, "-m", "xvmatch", "train", "--config",
            str(REPO / "configs" / "appearance_cpu.yaml"), "--stage", stage,
            f"--ckpt_path={checkpoints['fifo']}"]
    try:
        done = subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True,
                              timeout=PROMPT_S * 2)
    except subprocess.TimeoutExpired:
        fd = os.open(checkpoints["fifo"], os.O_WRONLY | os.O_NONBLOCK)
        os.close(fd)
        pytest.fail(f"train --ckpt_path FIFO did not finish in {PROMPT_S * 2} s")
    _one_line(done.returncode, done.stderr, f"--ckpt_path {checkpoints['fifo']}: is a FIFO")


# --------------------------------------------------------------------------------------------
# offset.json


@pytest.fixture
def tracks(track_files, tmp_path) -> Path:
    """A tracks folder as ``track`` writes it: the ground truth as tracks, and offset.json."""
    folder = tmp_path / "tracks"
    folder.mkdir()
    (folder / "top.txt").write_text(track_files["gt_top"].read_text())
    (folder / "hor.txt").write_text(track_files["gt_hor"].read_text())
    (folder / "offset.json").write_text('{"offset": 0}\n')
    return folder


@pytest.mark.parametrize(("record", "message"), [
    ('{"offset": -99999999999}', "field 'offset' must be in -100000..100000 frames (as "
     "--offset), got -99999999999"),
    ('{"offset": 100001}', "field 'offset' must be in -100000..100000"),
    ('{"offset": 3.0}', "field 'offset' must be an integer number of frames, got '3.0'"),
    ('{"offset": 1e999}', "field 'offset' must be an integer number of frames"),
    ('{"offset": NaN}', "field 'offset' must be an integer number of frames"),
    ('{"offset": "' + "9" * 4000 + '"}', "field 'offset' must be an integer"),
    ('{"offset": ' + "9" * 4000 + "}", "field 'offset' must be in -100000..100000 frames (as "
     "--offset), got 99999999999999999999..."),
    ("[3]", "not the offset record that xvmatch track or associate writes"),
    ('{"offset": 1}' + " " * 5000, "5,013 bytes, more than the 4,096 it may hold"),
    ("\xff", "not the offset record that xvmatch track or associate writes"),
])
def test_an_offset_record_out_of_range_is_one_line(track_files, tracks, capsys, record,
                                                   message) -> None:
    from xvmatch.commands._types import MAX_FRAME_OFFSET
    from xvmatch.formats.offset_record import read_offset_record

    path = tracks / "offset.json"
    path.write_bytes(record.encode("latin-1"))
    with pytest.raises(ValueError) as info:
        read_offset_record(path, MAX_FRAME_OFFSET)
    assert message in str(info.value) and str(info.value).startswith(str(path))
    argv = ["evaluate", "--tracks", tracks, "--top", track_files["gt_top"], "--hor",
            track_files["gt_hor"]]
    code, err = _cli(capsys, *argv)
    _one_line(code, err, f"{path}", message, "pass --offset N")


def test_an_offset_record_in_range_is_applied(track_files, tracks, capsys) -> None:
    from xvmatch.commands._types import MAX_FRAME_OFFSET
    from xvmatch.formats.offset_record import read_offset_record

    for offset in (-100_000, 0, 7, 100_000):
        (tracks / "offset.json").write_text(json.dumps({"offset": offset}))
        assert read_offset_record(tracks / "offset.json", MAX_FRAME_OFFSET) == offset
    (tracks / "offset.json").write_text('{"offset": 0}')
    code, err = _cli(capsys, "evaluate", "--tracks", tracks, "--top", track_files["gt_top"],
                     "--hor", track_files["gt_hor"], "--json")
    assert code == 0, err


def test_a_fifo_offset_record_is_refused_at_once(tracks) -> None:
    from xvmatch.commands.evaluate_tracks import tracked_offset

    (tracks / "offset.json").unlink()
    os.mkfifo(tracks / "offset.json")
    exc = _promptly(lambda: tracked_offset(tracks), tracks / "offset.json")
    assert isinstance(exc, ValueError) and "is a FIFO" in str(exc), exc


# --------------------------------------------------------------------------------------------
# offset --clip-start


@pytest.mark.parametrize("start", [28, 31, 10**6, 2**53])
def test_a_clip_start_beyond_the_video_is_refused(boxes, capsys, start) -> None:
    code, err = _cli(capsys, "offset", "--top", boxes["top"], "--hor", boxes["hor"],
                     "--clip-start", start, "--clip-length", "4", "--max-offset", "2",
                     "--image-size", "2688x1512")
    _one_line(code, err, f"--clip-start {start} is outside the horizontal video (frames "
              "1..30): a clip of 4 frames starts at 1..27")


def test_a_clip_start_inside_the_video_runs(boxes, capsys) -> None:
    for start in (1, 27):
        code, err = _cli(capsys, "offset", "--top", boxes["top"], "--hor", boxes["hor"],
                         "--clip-start", start, "--clip-length", "4", "--max-offset", "2",
                         "--image-size", "2688x1512", "--json")
        assert code == 0, err


def test_estimate_offset_refuses_a_clip_start_beyond_the_video() -> None:
    from xvmatch.cues.offset_estimation import clip_start_range, estimate_offset

    scene = simulate_box_scene(n_frames=30, seed=1)
    assert clip_start_range((1, 30), 4) == (1, 27)
    assert clip_start_range((5, 7), 10) == (5, 5)  # shorter than a clip: its first frame
    with pytest.raises(ValueError, match=r"clip_start 31 is outside the horizontal video "
                       r"\(frames 1\.\.30\): a clip of 4 frames starts in 1\.\.27"):
        estimate_offset(scene.top, scene.hor, 2688.0, clip_start=31, clip_length=4,
                        max_offset=2)


@pytest.mark.slow
def test_a_real_checkpoint_still_resumes(tiny_synth, tmp_path, capsys, monkeypatch) -> None:
    """A checkpoint the run wrote itself passes the check and resumes (read as weights only)."""
    pytest.importorskip("lightning")
    monkeypatch.chdir(tmp_path)
    data = tiny_synth["overview"]
    base = ["train", "--config", REPO / "configs" / "appearance_cpu.yaml",
            "--data.init_args.train_data", f"[{data}]", "--data.init_args.val_data", data,
            "--data.init_args.input_height", "32", "--data.init_args.input_width", "16",
            "--data.init_args.workers", "1",
            "--model.init_args.net.init_args.input_size", "[32, 16]",
            "--model.init_args.net.init_args.widths", "[4, 8, 8, 16]",
            "--trainer.default_root_dir", tmp_path, "--trainer.limit_train_batches", "1",
            "--trainer.limit_val_batches", "1", "--trainer.enable_progress_bar", "false"]
    code, err = _cli(capsys, *base, "--trainer.max_epochs", "1")
    assert code == 0, err
    last = sorted(tmp_path.rglob("last.ckpt"))
    assert last, "no last.ckpt written"
    code, err = _cli(capsys, *base, "--trainer.max_epochs", "2", "--ckpt_path", last[-1])
    assert code == 0, err
    code, err = _cli(capsys, *base, "--stage", "validate", "--ckpt_path", last[-1])
    assert code == 0, err
