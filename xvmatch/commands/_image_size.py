"""The command line's side of the horizontal image size rule: the rule itself (which size the
horizontal boxes belong to, and whether they fit it) lives in
:mod:`xvmatch.formats.box_image_size`; this module adds the one-line note a command prints when
it assumed the CVMHAT size, and the size a command settles from its inputs.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

from xvmatch.formats.box_image_size import ASSUMED, box_extent

__all__ = ["note_if_assumed", "settled_hor_size"]


def note_if_assumed(resolved: tuple[tuple[int, int], str], hor: Mapping,
                    hor_path: str | os.PathLike, quiet: bool = False,
                    option: str = "--image-size") -> None:
    """Print the one-line note on stderr when
    :func:`~xvmatch.formats.box_image_size.resolve_size` assumed the CVMHAT size (not with
    ``quiet``). Commands call it once every check has passed, as the work starts, so
    that a refused run prints its error line alone."""
    if quiet or resolved[1] != ASSUMED:
        return
    right, bottom = box_extent(hor)
    print(f"xvmatch: note: assuming {os.fspath(hor_path)}'s images are 2688x1512 (CVMHAT; its "
          f"boxes reach x {float(right):g}, y {float(bottom):g}); pass {option} WxH if not",
          file=sys.stderr)


def settled_hor_size(hor: Mapping, hor_path: str, image_size: tuple[int, int] | None,
                     images_size: tuple[int, int] | None = None, images: str | None = None,
                     cameras: str | None = None, quiet: bool = False,
                     ids: bool = True) -> tuple[tuple[int, int], str]:
    """The horizontal image size of ``hor`` (read from ``hor_path``) and where it comes from:
    ``image_size`` (``--image-size``), the size of the horizontal ``images`` (None without) or
    else the ``cameras``' ego camera, which must agree
    (:func:`~xvmatch.formats.box_image_size.resolve_size`); said when assumed."""
    from xvmatch.formats.box_image_size import resolve_size

    given = [] if image_size is None else [(image_size, "--image-size")]
    if images_size is not None:
        given.append((images_size, f"the horizontal images {images}"))
    elif cameras is not None:  # with images, each camera is checked against them
        from xvmatch.commands._model import ego_camera_size

        given.append(ego_camera_size(cameras))
    resolved = resolve_size(hor, hor_path, given, ids=ids)
    note_if_assumed(resolved, hor, hor_path, quiet)
    return resolved

