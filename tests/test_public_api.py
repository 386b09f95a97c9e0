"""The stable surface of ``xvmatch``: every public name resolves, lazily, without torch."""

from __future__ import annotations

import subprocess
import sys

import xvmatch


def test_every_public_name_resolves() -> None:
    for name in xvmatch.__all__:
        assert getattr(xvmatch, name) is not None, name
    assert set(dir(xvmatch)) >= set(xvmatch.__all__)


def test_import_is_lazy_and_torch_free() -> None:
    code = ("import sys, xvmatch; xvmatch.associate_sequence; xvmatch.run_ground_association; "
            "xvmatch.load_bundle; print(any(m == 'torch' or m.startswith('torch.') "
            "for m in sys.modules), 'xvmatch.inference.tracks.tracking' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out == ["False", "False"]


def test_unknown_name_is_an_attribute_error() -> None:
    try:
        xvmatch.no_such_thing  # noqa: B018
    except AttributeError as exc:
        assert "no_such_thing" in str(exc)
    else:
        raise AssertionError("no AttributeError")
