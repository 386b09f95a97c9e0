"""Progress callbacks of long library calls told to a progress bar.

The library reports progress through plain callbacks (no tqdm below the commands); a search
whose amount of work is known only as it goes (the offset search's coarse pass, then its fine
pass) tells ``progress(done, total)`` with a ``total`` that grows. :func:`growing_total` turns a
tqdm-like bar (``n``, ``total``, ``update``) into such a callback.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["growing_total"]


def growing_total(bar: Any) -> Callable[[int, int], None]:
    """``progress(done, total)`` that moves ``bar`` (a tqdm bar, shown or disabled) to
    ``done`` of ``total`` steps, ``total`` being the work known so far."""

    def tell(done: int, total: int) -> None:
        bar.total = int(total)
        bar.update(int(done) - int(bar.n))

    return tell
