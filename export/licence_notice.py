"""What a bundle says of its appearance trunk's origin: the manifest's backbone record and the
licence notice (NOTICE.txt) of weights fine-tuned from a package's ImageNet checkpoint, whose
licence the derived weights inherit."""

from __future__ import annotations

import importlib.metadata
import os
from pathlib import Path

from xvmatch.models.appearance_net import AppearanceNet, appearance_source

__all__ = ["NOTICE", "backbone_record", "licence_texts", "notice_text"]


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
