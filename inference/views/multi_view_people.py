"""One person id per box over several views: the joint program of every frame, or tracks.

The library side of ``xvmatch associate-multi``: given each frame's cost matrices of every view
pair (:func:`xvmatch.inference.views.multi_view_costs.multi_view_costs`), give each box of each
view a person id, the same id in two views of a frame being the same person. Frame by frame
(:func:`~xvmatch.inference.views.multi_view_assignment.solve_multi_view`, or its greedy fallback
:func:`~xvmatch.inference.views.multi_view_assignment.consistent_hungarian`) the ids are unique
over the whole output and do not carry over frames; with tracks
(:func:`~xvmatch.inference.views.multi_ego_tracking.track_multi_view`) they follow the tracklets.
Video mode (``--mode``, each view's own track ids) builds on this answer
(:func:`~xvmatch.inference.views.multi_ego_video.video_people`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

__all__ = ["PeopleOptions", "ViewPeople", "assign_people", "solve_frame"]


@dataclass(frozen=True)
class PeopleOptions:
    """How :func:`assign_people` solves: ``solver`` ``"mip"`` (the joint program with HiGHS,
    ``time_limit`` seconds per program) or ``"greedy"`` (pairwise Hungarian made consistent);
    ``tracks``: follow people over time in clips of ``clip_length`` frames."""

    solver: str = "mip"
    time_limit: float = 30.0
    tracks: bool = False
    clip_length: int = 10


@dataclass(frozen=True)
class ViewPeople:
    """The ids :func:`assign_people` gives: ``person[v]`` maps a row id of view ``v``'s boxes
    (the order of ``views``) to its person id (1, 2, ...; a row without a box on a solved frame
    is absent); ``n_people`` ids are used; ``n_fallback`` programs spent their budget of work
    or time limit, or failed, and used the best consistent answer found."""

    person: list[dict[int, int]]
    n_people: int
    n_fallback: int


def assign_people(views: Sequence[Mapping], problems: Mapping, frames: Sequence[int],
                  options: PeopleOptions) -> ViewPeople:
    """Person ids for every box of ``views`` (the top view first; ``{frame: FrameBoxes}`` each)
    from ``problems`` (``{frame: FrameProblem}`` of every frame in ``frames``)."""
    if options.tracks:
        from xvmatch.inference.views.multi_ego_tracking import track_multi_view

        tracks = track_multi_view(views, problems, options.clip_length, solver=options.solver,
                                  time_limit=options.time_limit)
        person: list[dict[int, int]] = [{} for _ in views]
        for v, per_frame in enumerate(tracks.person):
            for f, ids in per_frame.items():
                person[v].update(zip(views[v][f].ids.tolist(), ids.tolist(), strict=True))
        return ViewPeople(person, tracks.n_people, tracks.statuses.count("fallback"))
    return _frame_by_frame(views, problems, frames, options)


def solve_frame(problem, options: PeopleOptions):
    """One frame's cycle-consistent program with ``options``' solver: the solution, and
    whether it fell back on the best consistent answer found (the MIP's budget spent)."""
    from xvmatch.inference.views.multi_view_assignment import (
        consistent_hungarian,
        solve_multi_view,
    )

    if options.solver == "mip":
        sol = solve_multi_view(problem.sizes, problem.costs, problem.gamma, options.time_limit)
        return sol, sol.status == "fallback"
    return consistent_hungarian(problem.sizes, problem.costs, problem.gamma), False


def _frame_by_frame(views: Sequence[Mapping], problems: Mapping, frames: Sequence[int],
                    options: PeopleOptions) -> ViewPeople:
    """:func:`assign_people` without tracks: each frame's program, ids counted on over frames."""
    person: list[dict[int, int]] = [{} for _ in views]
    next_id, n_fallback = 1, 0
    for f in frames:
        sol, fell_back = solve_frame(problems[f], options)
        n_fallback += fell_back
        for v, ids in enumerate(sol.person):
            rec = views[v].get(f)
            for row, pid in zip(rec.ids.tolist() if rec is not None else [], ids.tolist(),
                                strict=True):
                person[v][row] = next_id + pid
        next_id += int(max((int(ids.max()) + 1 for ids in sol.person if ids.size), default=0))
    return ViewPeople(person, next_id - 1, n_fallback)
