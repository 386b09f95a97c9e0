"""A piecewise-constant choice among a track's candidate labels over its frames (a Viterbi with a
switch cost and a free state), shared by the two-view video consensus
(:mod:`xvmatch.inference.linking.pair_consensus`: a top track's partner among the horizontal
tracks) and the multi-camera evidence split (:mod:`xvmatch.inference.views.multicam_evidence`:
a camera track's partner in another camera among the tracks its pieces were linked to).
"""

from __future__ import annotations

import numpy as np

__all__ = ["cheapest_path", "label_path"]


def label_path(obs: np.ndarray, here: np.ndarray, switch_cost: float,
               free_cost: float, absent_cost: float | None = None) -> np.ndarray:
    """Viterbi over one track's frames: state 0 follows each frame's own label at
    ``free_cost`` a frame; state ``j >= 1`` holds candidate ``j``, at 0 a frame where that
    frame's label agrees and 1 where it does not, and ``absent_cost`` (``free_cost`` unless
    given) where the candidate is absent from the frame (its absence says nothing for or
    against it: a person out of the handheld camera's view for a while stays that track's
    partner); changing state costs ``switch_cost``.

    Args:
        obs: ``(T,)`` index of the frame's label among the candidates (1-based), 0 for none.
        here: ``(T, S)`` bool, candidate ``j`` present in the frame (column 0 unused).
        switch_cost: frames of disagreement a change of state must save.
        free_cost: cost a frame of the free state; a candidate holds over a stretch where it
            agrees with more than ``1 - free_cost`` of the frames.
        absent_cost: cost a frame of a candidate absent from it (None: ``free_cost``).

    Returns:
        ``(T,)`` the chosen state per frame.

    Example:
        >>> import numpy as np
        >>> label_path(np.array([1, 1, 2, 1, 1]), np.ones((5, 3), bool), 2.0, 0.5).tolist()
        [1, 1, 1, 1, 1]
    """
    cols = np.arange(here.shape[1])
    cost = np.where(here, (obs[:, None] != cols[None, :]).astype(float),
                    free_cost if absent_cost is None else absent_cost)
    cost[:, 0] = free_cost
    return cheapest_path(cost, switch_cost)


def cheapest_path(cost: np.ndarray, switch_cost: float) -> np.ndarray:
    """The state sequence of least total cost: ``cost[k, j]`` for being in state ``j`` at
    step ``k``, plus ``switch_cost`` for every change of state (a Viterbi; on a tie the path
    keeps its state).

    In Python floats, the same IEEE sums and comparisons as numpy's: a track has a handful of
    states, where a numpy call per step cost five times the arithmetic.

    Args:
        cost: ``(T, S)`` cost of each state at each step (no NaN).
        switch_cost: cost of a change of state.

    Returns:
        ``(T,)`` the chosen state per step.

    Raises:
        ValueError: a NaN cost.
    """
    cost = np.asarray(cost, dtype=float)
    if np.isnan(cost).any():
        raise ValueError("cheapest_path: a cost is NaN")
    rows = cost.tolist()
    n, switch = len(rows), float(switch_cost)
    back: list[list[int]] = [[]]  # back[k]: each state's state at step k - 1 (none at 0)
    total = rows[0]
    for k in range(1, n):
        low = min(total)
        best = total.index(low)  # the first lowest, as argmin
        limit = low + switch
        back.append([j if t <= limit else best for j, t in enumerate(total)])
        total = [(t if t <= limit else limit) + c for t, c in zip(total, rows[k], strict=True)]
    path = np.zeros(n, dtype=np.int64)
    path[-1] = total.index(min(total))
    for k in range(n - 1, 0, -1):
        path[k - 1] = back[k][path[k]]
    return path
