"""Export a trained matcher file to a deployable bundle: two ONNX graphs and a manifest.

``xvmatch export --model M.pt --out BUNDLE/`` writes::

    BUNDLE/manifest.json      format, versions, preprocessing, gamma, sha256, parity figures
    BUNDLE/matcher.onnx       geometry encoder + cue fusion + dustbin + log-Sinkhorn: cost 1 - P
    BUNDLE/appearance.onnx    the Siamese branch: uint8 BGR crops to unit descriptors (only
                              when the matcher takes the appearance cue)

What is inside the graphs and what is not: the graphs hold every learned operation (the
appearance network with its input normalisation; the matcher from padded feature tensors to the
cost matrix, Sinkhorn included). Outside them, in numpy (:mod:`xvmatch.geometry.matcher_inputs`,
:mod:`xvmatch.datasets.crops`): cropping, the spatial-distribution search that builds the
geometry features, the camera cues, the appearance cost of two descriptors, and the Hungarian
assignment with the non-association cost gamma (:func:`xvmatch.inference.assignment.assign`).

Every axis that varies is dynamic (frames, crops, people in each view, hypotheses), and empty
sets are masks, never branches. The legacy TorchScript-based exporter is used (opset 17): it
needs no extra package, and the parity gate checks its output. Parity at export: the torch
modules and the ONNX graphs (run by onnxruntime) are compared on held-out synthetic frames in
each input setting (boxes only, with images, with images and cameras) plus edge cases (one
person, an empty view in a padded batch); the export fails, writing nothing, unless every cost
agrees within :data:`PARITY_TOLERANCE` and every frame's Hungarian assignment is identical.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import os
import shutil
import tempfile
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from xvmatch.geometry.matcher_inputs import MatcherInputs, collate_inputs
from xvmatch.geometry.ray_priors import DEFAULT_BETA, METRIC_MARGIN
from xvmatch.geometry.spatial_features import (
    FEATURE_VERSION,
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
)
from xvmatch.inference.assignment import assign
from xvmatch.inference.bundle import (
    APPEARANCE_INPUT,
    BUNDLE_FORMAT,
    BUNDLE_FORMAT_VERSION,
    MANIFEST,
    MATCHER_INPUTS,
    MATCHER_OUTPUT,
    OPSET,
)
from xvmatch.models.appearance_net import AppearanceNet, appearance_source
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.training.matcher_file import LoadedMatcher, load_matcher

__all__ = ["NOTICE", "PARITY_TOLERANCE", "ExportError", "backbone_record", "check_replaceable",
           "export_bundle", "licence_texts", "notice_text", "parity_frames"]

PARITY_TOLERANCE: float = 1e-4
"""Largest |cost_torch - cost_onnx| accepted at export."""


class ExportError(ValueError):
    """The export cannot produce a faithful bundle; the message gives the figures."""


class AppearanceGraph(nn.Module):
    """The appearance network with its preprocessing: ``(B, H, W, 3)`` uint8 BGR crops on the
    [0, 255] scale to ``(B, D)`` unit descriptors (what ``appearance.onnx`` computes)."""

    def __init__(self, net: AppearanceNet) -> None:
        super().__init__()
        self.net = net.eval()

    def forward(self, crops: Tensor) -> Tensor:
        """Descriptors of a batch of crops."""
        return self.net.embed_crops(crops)


class MatcherGraph(nn.Module):
    """The matcher from padded inputs to the ``(B, M, N)`` cost (what ``matcher.onnx``
    computes)."""

    def __init__(self, matcher: CrossViewMatcher) -> None:
        super().__init__()
        self.matcher = matcher.eval()

    def forward(self, top: Tensor, hor: Tensor, hyp: Tensor, pair: Tensor, top_mask: Tensor,
                hor_mask: Tensor, hyp_mask: Tensor, cues: Tensor, cue_mask: Tensor) -> Tensor:
        """Cost ``1 - P`` of a padded batch (1 on padding)."""
        return self.matcher(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues,
                            cue_mask).cost


_DYNAMIC = {
    "top": {0: "frames", 1: "top_people"},
    "hor": {0: "frames", 1: "hor_people"},
    "hyp": {0: "frames", 1: "hypotheses"},
    "pair": {0: "frames", 1: "hypotheses", 2: "top_people", 3: "hor_people"},
    "top_mask": {0: "frames", 1: "top_people"},
    "hor_mask": {0: "frames", 1: "hor_people"},
    "hyp_mask": {0: "frames", 1: "hypotheses"},
    "cues": {0: "frames", 1: "top_people", 2: "hor_people"},
    "cue_mask": {0: "frames"},
    MATCHER_OUTPUT: {0: "frames", 1: "top_people", 2: "hor_people"},
}


def _example_batch(n_cues: int) -> tuple[Tensor, ...]:
    """A batch of 2 frames with unequal sizes and some padding (so no axis is specialised)."""
    g = torch.Generator().manual_seed(0)
    b, m, n, h = 2, 3, 4, 2
    return (
        torch.randn(b, m, len(TOP_FEATURES), generator=g),
        torch.randn(b, n, len(HOR_FEATURES), generator=g),
        torch.randn(b, h, len(HYP_FEATURES), generator=g),
        torch.randn(b, h, m, n, len(PAIR_FEATURES), generator=g),
        torch.tensor([[True, True, True], [True, True, False]]),
        torch.tensor([[True, True, True, True], [True, False, False, False]]),
        torch.tensor([[True, True], [True, False]]),
        torch.rand(b, m, n, n_cues, generator=g),
        torch.ones(b, n_cues, dtype=torch.bool),
    )


def _onnx_export(module: nn.Module, args: tuple[Tensor, ...], path: Path, names: list[str],
                 outputs: list[str], dynamic: dict) -> None:
    """Export an eval-mode module (the exporter restores the module's own mode afterwards, so
    it must already be eval: a wrapper left in training mode would put BatchNorm back in it)."""
    if module.training:
        raise ValueError("export an eval-mode module")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tracer warnings about Python values are expected
        torch.onnx.export(module, args, os.fspath(path), dynamo=False, input_names=names,
                          output_names=outputs, dynamic_axes=dynamic, opset_version=OPSET,
                          do_constant_folding=True)


def _set_metadata(path: Path, props: dict[str, str]) -> None:
    import onnx

    model = onnx.load(os.fspath(path))
    del model.metadata_props[:]
    for key, value in props.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    onnx.save(model, os.fspath(path))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _session(path: Path):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    return ort.InferenceSession(os.fspath(path), options, providers=["CPUExecutionProvider"])


def _matcher_costs_torch(matcher: CrossViewMatcher, batch: dict[str, np.ndarray]) -> np.ndarray:
    with torch.inference_mode():
        out = matcher(*(torch.from_numpy(batch[k]) for k in MATCHER_INPUTS))
    return out.cost.numpy()


def _matcher_costs_onnx(session, batch: dict[str, np.ndarray]) -> np.ndarray:
    wanted = {i.name for i in session.get_inputs()}
    return session.run([MATCHER_OUTPUT], {k: batch[k] for k in MATCHER_INPUTS if k in wanted})[0]


def _compare_matcher(matcher: CrossViewMatcher, session, frames: Sequence[MatcherInputs],
                     gamma: float, batch_size: int = 16) -> dict:
    """Parity figures of one input setting."""
    worst, same, n_pairs = 0.0, 0, 0
    for start in range(0, len(frames), batch_size):
        chunk = list(frames[start : start + batch_size])
        batch = collate_inputs(chunk)
        ref = _matcher_costs_torch(matcher, batch)
        got = _matcher_costs_onnx(session, batch)
        if got.shape != ref.shape or not np.isfinite(got).all():
            return {"frames": len(frames), "max_abs_cost_diff": float("inf"),
                    "assignments_identical": 0, "error": f"shape {got.shape} / non-finite"}
        for k, f in enumerate(chunk):
            m, n = f.features.top.shape[0], f.features.hor.shape[0]
            a, b = ref[k, :m, :n].astype(np.float64), got[k, :m, :n].astype(np.float64)
            if a.size:
                worst = max(worst, float(np.abs(a - b).max()))
            same += int(np.array_equal(assign(a, gamma), assign(b, gamma)))
            n_pairs += int(assign(a, gamma).shape[0])
    return {"frames": len(frames), "max_abs_cost_diff": worst, "assignments_identical": same,
            "pairs": n_pairs}


def parity_frames(
    loaded: LoadedMatcher,
    data: str | os.PathLike | None = None,
    *,
    seed: int = 424242,
    progress: Callable[[str], None] | None = None,
) -> tuple[dict[str, list[MatcherInputs]], np.ndarray]:
    """Held-out synthetic frames in each input setting, and the crops they were cut from.

    Args:
        loaded: the matcher (its feature configuration, cues and appearance network).
        data: synthetic dataset folder(s) to draw from (``xvmatch synth``); None renders a small
            one of each scenario (seed ``seed``, never a training seed) in a temporary folder.
        seed: seed of the rendered scenes.
        progress: called with a line of text at each stage.

    Returns:
        ``({setting: frames}, crops (C, H, W, 3) uint8)``; settings ``boxes`` always,
        ``images`` and ``cameras`` when the matcher takes those cues.
    """
    from xvmatch.datasets.crops import box_crops
    from xvmatch.datasets.pair_trials import TrialConfig, dataset_trials
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.geometry.matcher_inputs import FrameCameras, appearance_cost, matcher_inputs

    names = tuple(loaded.matcher.cues)
    tmp = None
    folders: list[Path]
    if data is None:
        tmp = Path(tempfile.mkdtemp(prefix="xvmatch-parity-"))
        folders = []
        for k, scenario in enumerate(("drone", "overview")):
            folder = tmp / scenario
            config = SynthConfig(scenario=scenario, n_people=(2, 12))
            generate_dataset(folder, config, n_scenes=2, n_frames=2, seed=seed + k)
            folders.append(folder)
    else:
        folders = [Path(data)]
    try:
        if progress:
            progress(f"parity frames from {', '.join(map(str, folders))}")
        net = loaded.appearance
        crops_all: list[np.ndarray] = []

        def coster(top_image, top_boxes, hor_image, hor_boxes):
            size = net.preprocessing.crop_size
            a = box_crops(top_image, top_boxes, size, loaded.crop_context)
            b = box_crops(hor_image, hor_boxes, size, loaded.crop_context)
            crops_all.extend([a, b])
            with torch.inference_mode():
                da = net.embed_crops(torch.from_numpy(a)).numpy() if len(a) else np.zeros(
                    (0, net.embedding_dim), np.float32)
                db = net.embed_crops(torch.from_numpy(b)).numpy() if len(b) else np.zeros(
                    (0, net.embedding_dim), np.float32)
            return appearance_cost(da, db)

        trials = []
        for folder in folders:
            trials += dataset_trials(folder, TrialConfig(),
                                     coster=coster if net is not None else None)
        settings: dict[str, list[MatcherInputs]] = {"boxes": []}
        if "app" in names:
            settings["images"] = []
        if "ray" in names or "cheir" in names:
            settings["cameras"] = []
        config = loaded.feature_config
        for t in trials:
            size = t.cameras["ego"].image_size
            cams = FrameCameras(t.cameras["top"], t.cameras["ego"])
            plain = matcher_inputs(t.top_boxes, t.ego_boxes, size, config, names)
            settings["boxes"].append(plain)
            if "images" in settings:
                settings["images"].append(matcher_inputs(t.top_boxes, t.ego_boxes, size, config,
                                                         names, app=t.app))
            if "cameras" in settings:
                settings["cameras"].append(matcher_inputs(t.top_boxes, t.ego_boxes, size, config,
                                                          names, cameras=cams, app=t.app))
        # Edge cases: one person per view, and an empty view padded in a batch.
        t = max(trials, key=lambda t: len(t.top_boxes) * len(t.ego_boxes))
        size = t.cameras["ego"].image_size
        edge = [
            matcher_inputs(t.top_boxes[:1], t.ego_boxes[:1], size, config, names),
            matcher_inputs(t.top_boxes, t.ego_boxes[:0], size, config, names),
            matcher_inputs(t.top_boxes[:0], t.ego_boxes, size, config, names),
            matcher_inputs(t.top_boxes, t.ego_boxes, size, config, names),
        ]
        settings["edge cases"] = edge
        crops = np.concatenate(crops_all) if crops_all else np.zeros((0, 1, 1, 3), np.uint8)
        return settings, crops
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


def _appearance_parity(net: AppearanceNet, session, crops: np.ndarray) -> dict:
    if crops.shape[0] == 0:
        return {"crops": 0, "max_abs_descriptor_diff": 0.0}
    with torch.inference_mode():
        ref = net.embed_crops(torch.from_numpy(crops)).numpy()
    got = np.concatenate([session.run(None, {APPEARANCE_INPUT: crops[k : k + 64]})[0]
                          for k in range(0, crops.shape[0], 64)])
    return {"crops": int(crops.shape[0]),
            "max_abs_descriptor_diff": float(np.abs(ref - got).max())}


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("xvmatch", "torch", "onnx", "onnxruntime"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            out[name] = "unknown"
    return out


def backbone_record(net: AppearanceNet) -> dict[str, str]:
    """The manifest's ``appearance.backbone``: the architecture and where its trunk's initial
    weights came from (for an ImageNet initialisation: the registry package, its version and
    licence, which the derived weights inherit)."""
    source = appearance_source(net)
    if source is None:
        return {"arch": net.arch, "init": "random"}
    return {"arch": net.arch, "init": "imagenet",
            **{k: str(source.get(k, "unknown")) for k in ("package", "version", "licence")}}


NOTICE = "NOTICE.txt"
"""The licence notice a bundle carries when its appearance trunk started from third-party
weights (the derived weights inherit the checkpoint's licence)."""


def licence_texts(package: str) -> list[tuple[str, str]]:
    """``(file name, text)`` of the licence files an installed distribution ships (LICENSE,
    COPYING, NOTICE in its metadata or package); empty when it is absent or ships none."""
    try:
        files = importlib.metadata.distribution(package).files or []
    except importlib.metadata.PackageNotFoundError:
        return []
    out = []
    for f in files:
        if f.name.upper().startswith(("LICENSE", "LICENCE", "COPYING", "NOTICE")):
            path = Path(os.fspath(f.locate()))
            if path.is_file():
                out.append((f.name, path.read_text(errors="replace").strip()))
    return out


def notice_text(net: AppearanceNet) -> str | None:
    """The text of a bundle's :data:`NOTICE`, or None for a trunk trained from scratch: which
    package's weights the appearance network was fine-tuned from, its licence, and the licence
    text found in the installed distribution."""
    source = appearance_source(net)
    if source is None:
        return None
    package = str(source.get("package", "unknown"))
    lines = [
        "The appearance network of this bundle (appearance.onnx, and appearance_int8.onnx when "
        "present) was",
        f"fine-tuned (modified) from the ImageNet weights of the {net.arch} trunk shipped in the "
        f"Python package",
        f"{package} {source.get('version', 'unknown')} (file {source.get('weights', 'unknown')}),"
        f" licence {source.get('licence', 'unknown')}.",
        "Those weights' licence applies to the derived weights; its text, as the package ships "
        "it, follows.",
    ]
    texts = licence_texts(package)
    if not texts:
        lines.append(f"(no licence file found in the installed {package}; see its project page)")
    for name, text in texts:
        lines += ["", f"--- {package}: {name} ---", text]
    return "\n".join(lines) + "\n"


def _write_graphs(loaded: LoadedMatcher, folder: Path) -> dict:
    """Export the graphs into ``folder``; the manifest's file records."""
    matcher = loaded.matcher.eval()
    names = list(MATCHER_INPUTS)
    records: dict = {}
    path = folder / "matcher.onnx"
    _onnx_export(MatcherGraph(matcher).eval(), _example_batch(matcher.n_cues), path, names,
                 [MATCHER_OUTPUT], {k: v for k, v in _DYNAMIC.items() if k in names or
                                    k == MATCHER_OUTPUT})
    layout = {"top": list(TOP_FEATURES), "hor": list(HOR_FEATURES), "hyp": list(HYP_FEATURES),
              "pair": list(PAIR_FEATURES)}
    _set_metadata(path, {
        "xvmatch.role": "matcher",
        "xvmatch.feature_version": str(FEATURE_VERSION),
        "xvmatch.feature_config": json.dumps(loaded.feature_config.to_dict()),
        "xvmatch.feature_layout": json.dumps(layout),
        "xvmatch.cues": json.dumps(list(matcher.cues)),
        "xvmatch.gamma": repr(loaded.gamma),
        "xvmatch.output": "cost = 1 - P (B, M, N); Hungarian with gamma outside the graph",
    })
    records["matcher"] = {"file": path.name, "inputs": names, "output": MATCHER_OUTPUT}
    net = loaded.appearance
    if net is not None:
        path = folder / "appearance.onnx"
        h, w = net.preprocessing.input_size
        example = torch.randint(0, 256, (2, h, w, 3), dtype=torch.uint8,
                                generator=torch.Generator().manual_seed(0))
        _onnx_export(AppearanceGraph(net).eval(), (example,), path, [APPEARANCE_INPUT],
                     ["descriptors"], {APPEARANCE_INPUT: {0: "crops"}, "descriptors": {0: "crops"}})
        prep = {
            "crop_size": [w, h],
            "input": "uint8 NHWC on the [0, 255] scale",
            "colour_order": "BGR",
            "mean": list(net.preprocessing.mean),
            "std": list(net.preprocessing.std),
            "normalisation": "RGB = BGR reversed; (x / 255 - mean) / std, inside the graph",
            "context": loaded.crop_context,
            "resize": "cv2.INTER_AREA when shrinking, cv2.INTER_LINEAR when enlarging",
        }
        _set_metadata(path, {
            "xvmatch.role": "appearance",
            "xvmatch.preprocessing": json.dumps(prep),
            "xvmatch.output": "unit descriptors (B, D); cost of a pair |a - b| / 2",
        })
        notice = notice_text(net)
        if notice is not None:
            (folder / NOTICE).write_text(notice)
        records["appearance"] = {"file": path.name, "arch": net.arch,
                                 "embedding_dim": net.embedding_dim, "precision": "fp32", **prep,
                                 "backbone": backbone_record(net)}
    return records


def _int8_accuracy(folder: Path, manifest: dict, data: Path, scenes: Sequence[str],
                   files: dict[str, str]) -> dict[str, dict]:
    """Eq. 9 accuracy and CVIDF1 (percent) of the matcher with images (and with images and
    cameras, when it takes camera cues) on ``scenes`` of ``data``, ground-truth boxes and
    detector noise pooled, for each appearance file of ``files`` ({label: file name})."""
    from xvmatch.datasets.pair_trials import TrialConfig, scene_trials
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.evaluation.cross_view_metrics import count_pair, summarize
    from xvmatch.geometry.matcher_inputs import (
        INPUT_SETTINGS,
        FrameCameras,
        appearance_cost,
        matcher_inputs,
    )
    from xvmatch.inference.bundle import Bundle, read_manifest
    from xvmatch.inference.learned_association import LearnedMatcher

    spec = read_manifest(folder)
    matcher_session = _session(folder / manifest["matcher"]["file"])
    dataset = SyntheticDataset(data)
    index = {name: k for k, name in enumerate(dataset.scene_names)}
    settings = ["images"] + (["images+cameras"] if "ray" in spec.cues else [])
    out: dict[str, dict] = {}
    for label, file in files.items():
        matcher = LearnedMatcher(Bundle(spec, matcher_session, _session(folder / file)))

        def coster(ti, tb, ei, eb, m=matcher):
            return appearance_cost(m.descriptors(ti, tb), m.descriptors(ei, eb))

        trials = [t for name in scenes
                  for t in scene_trials(dataset.scene(name), index[name], TrialConfig(),
                                        coster=coster)]
        record = {}
        for setting in settings:
            _, rectified = INPUT_SETTINGS[setting]
            inputs = [matcher_inputs(
                t.top_boxes, t.ego_boxes, t.cameras["ego"].image_size, spec.feature_config,
                spec.cues, app=t.app,
                cameras=FrameCameras(t.cameras["top"], t.cameras["ego"]) if rectified else None)
                for t in trials]
            counts = []
            for t, f, c in zip(trials, inputs, matcher.costs(inputs), strict=True):
                full = np.empty_like(c)
                full[np.ix_(f.features.top_order, f.features.hor_order)] = c
                counts.append(count_pair(t.gt_top_ids, t.gt_ego_ids, t.det_top_ids,
                                         t.det_ego_ids, assign(full, spec.gamma),
                                         frame=t.frame))
            s = summarize(counts)
            record[setting] = {"acc9": round(s.acc9, 3), "cvidf1": round(s.cvidf1, 3),
                               "trials": len(trials)}
        out[label] = record
    return out


def _add_int8(folder: Path, manifest: dict, loaded: LoadedMatcher, data: Path,
              progress: Callable[[str], None] | None) -> None:
    """Quantise the appearance graph (each calibration method), keep the best by measured
    accuracy as ``appearance_int8.onnx`` and record everything in ``manifest``."""
    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.export.int8 import CALIBRATION_METHODS, calibration_crops, quantize_appearance

    names = SyntheticDataset(data).scene_names
    calibrate, measure = names[0::2], names[1::2]
    if not measure:
        raise ExportError(f"{os.fspath(data)}: INT8 calibration needs at least two scenes "
                          "(even ones calibrate, odd ones measure the accuracy)")
    app = manifest["appearance"]
    crops = calibration_crops(data, tuple(app["crop_size"]), loaded.crop_context, calibrate)
    files = {"fp32": app["file"]}
    for method in CALIBRATION_METHODS:
        files[method] = f"appearance_int8_{method}.onnx"
        quantize_appearance(folder / app["file"], folder / files[method], crops, method,
                            APPEARANCE_INPUT, progress)
    if progress:
        progress(f"measuring FP32 and INT8 accuracy on {len(measure)} held-out scenes")
    accuracy = _int8_accuracy(folder, manifest, data, measure, files)
    best = max(CALIBRATION_METHODS,
               key=lambda m: (accuracy[m]["images"]["acc9"], -CALIBRATION_METHODS.index(m)))
    final = folder / "appearance_int8.onnx"
    os.replace(folder / files[best], final)
    for method in CALIBRATION_METHODS:
        (folder / files[method]).unlink(missing_ok=True)
    app["int8"] = {
        "file": final.name,
        "sha256": _sha256(final),
        "format": "QDQ, per-channel INT8 weights, UINT8 activations (onnxruntime "
                  "quantize_static after quant_pre_process)",
        "calibration": {"method": best, "methods_tried": list(CALIBRATION_METHODS),
                        "crops": int(crops.shape[0]), "data": os.fspath(data),
                        "scenes": list(calibrate)},
        "accuracy": {"measured_on": {"data": os.fspath(data), "scenes": list(measure),
                                     "settings": "ground-truth boxes and detector noise"},
                     "fp32": accuracy["fp32"], "int8": accuracy[best],
                     "by_method": {m: accuracy[m] for m in CALIBRATION_METHODS}},
    }


def _bundle_files(folder: Path) -> set[str] | None:
    """The names of the files an export wrote into ``folder``, from its manifest; None when
    ``folder`` holds no xvmatch bundle manifest."""
    try:
        doc = json.loads((folder / MANIFEST).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != BUNDLE_FORMAT:
        return None
    names = {MANIFEST, NOTICE}
    for key in ("matcher", "appearance"):
        record = doc.get(key)
        if isinstance(record, dict):
            names.add(str(record.get("file")))
            if isinstance(record.get("int8"), dict):
                names.add(str(record["int8"].get("file")))
    return names


def check_replaceable(out: str | os.PathLike) -> None:
    """``out`` may be written by an export: absent, an empty folder, or a bundle an export
    wrote, holding only the files its manifest lists (replacing it deletes nothing else).

    Raises:
        ExportError: a file, or a folder that is not such a bundle (a user's folder that
            happens to hold a ``manifest.json`` included).
    """
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return
    if out.is_symlink() or not out.is_dir():
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder; choose a new "
                          "folder")
    present = {p.name for p in out.iterdir()}
    if not present:
        return
    known = _bundle_files(out)
    if known is None:
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder (no xvmatch "
                          f"bundle {MANIFEST}); choose a new folder")
    foreign = sorted(present - known)
    if foreign:
        raise ExportError(f"{os.fspath(out)}: exists and is not a bundle folder: it also holds "
                          f"{', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}, "
                          "which xvmatch export did not write; choose a new folder")


def export_bundle(
    model: str | os.PathLike | LoadedMatcher,
    out: str | os.PathLike,
    *,
    parity_data: str | os.PathLike | None = None,
    int8_calibration: str | os.PathLike | None = None,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Export a matcher file to a bundle folder, checking parity first (see the module
    docstring); nothing is left at ``out`` when the export fails.

    Args:
        model: a matcher file (``xvmatch fit-geometry`` or the matcher training), ``"default"``,
            or a loaded one.
        out: the bundle folder to write (created; a bundle an export wrote there is
            replaced, anything else refused: :func:`check_replaceable`).
        parity_data: synthetic dataset folder for the parity check (default: render a small
            held-out one).
        int8_calibration: synthetic dataset folder: also write a static INT8 appearance
            network, calibrated on its even scenes, its accuracy measured on the odd ones
            (:mod:`xvmatch.export.int8`); the runtime uses it unless asked for FP32.
        progress: called with a line of text at each stage.

    Returns:
        The manifest written.

    Raises:
        ExportError: parity not reached (the figures are in the message), or ``out`` is a
            file or a non-empty folder that is not a bundle holding only its own files.
        MatcherFileError: an unusable matcher file.
    """
    out = Path(out)
    check_replaceable(out)
    loaded = model if isinstance(model, LoadedMatcher) else load_matcher(model)
    source = Path(loaded.path) if loaded.path else None
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        if progress:
            progress("exporting the ONNX graphs")
        records = _write_graphs(loaded, tmp)
        frames, crops = parity_frames(loaded, parity_data, progress=progress)
        if progress:
            progress("checking parity (torch against onnxruntime)")
        parity: dict = {}
        session = _session(tmp / records["matcher"]["file"])
        for setting, items in frames.items():
            parity[setting] = _compare_matcher(loaded.matcher, session, items, loaded.gamma)
        if loaded.appearance is not None:
            app_session = _session(tmp / records["appearance"]["file"])
            parity["appearance"] = _appearance_parity(loaded.appearance, app_session, crops)
        failed = [
            f"{s}: max |cost diff| {p['max_abs_cost_diff']:.2e}, identical assignments "
            f"{p['assignments_identical']}/{p['frames']}"
            for s, p in parity.items()
            if "frames" in p and (p["max_abs_cost_diff"] > PARITY_TOLERANCE
                                  or p["assignments_identical"] != p["frames"])
        ]
        if "appearance" in parity and parity["appearance"]["max_abs_descriptor_diff"] > \
                PARITY_TOLERANCE:
            failed.append(f"appearance: max |descriptor diff| "
                          f"{parity['appearance']['max_abs_descriptor_diff']:.2e}")
        if failed:
            raise ExportError("ONNX parity failed (tolerance "
                              f"{PARITY_TOLERANCE:g}): " + "; ".join(failed))
        for record in records.values():
            record["sha256"] = _sha256(tmp / record["file"])
        manifest = {
            "format": BUNDLE_FORMAT,
            "format_version": BUNDLE_FORMAT_VERSION,
            "opset": OPSET,
            "created_by": _versions(),
            "feature_version": FEATURE_VERSION,
            "feature_config": loaded.feature_config.to_dict(),
            "gamma": loaded.gamma,
            "cues": list(loaded.matcher.cues),
            "camera_cues": {"margin": METRIC_MARGIN, "beta": DEFAULT_BETA},
            "matcher": records["matcher"],
            "appearance": records.get("appearance"),
            "parity": {"tolerance": PARITY_TOLERANCE, **parity},
            "source": {"file": source.name if source else None,
                       "sha256": _sha256(source) if source and source.is_file() else None},
            "meta": loaded.meta,
        }
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        if int8_calibration is not None:
            if loaded.appearance is None:
                raise ExportError("--int8 quantises the appearance network, and this matcher "
                                  "has none")
            _add_int8(tmp, manifest, loaded, Path(int8_calibration), progress)
            (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # as mkdir would make it (mkdtemp's is 0700)
        if out.exists():
            check_replaceable(out)  # again: the folder may have changed during the export
            shutil.rmtree(out)
        os.replace(tmp, out)
        return manifest
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
