"""The command line's side of the horizontal image size rule: the rule itself (which size the
horizontal boxes belong to, and whether they fit it) lives in
:mod:`xvmatch.formats.box_image_size`; this module adds the one-line note a command prints when
it assumed the CVMHAT size.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Mapping

from xvmatch.formats.box_image_size import ASSUMED, box_extent

__all__ = ["note_if_assumed"]


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
