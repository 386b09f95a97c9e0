"""Tests of the spatial-distribution vectors (xvmatch.cues.spatial_vectors, CVMHAT Eqs. 5-10).

Conventions pinned here (from the module docstring): top-image angles are counter-clockwise on
screen, ``phi = atan2(-(v - v_O), u - u_O)``; theta is the optical axis in that convention, so a
camera with theta = 0 looks towards +u and its left is -v (up on screen).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from xvmatch.core import kernel_choice
from xvmatch.cues.spatial_vectors import (
    REFERENCE_SIZE,
    box_centres,
    horizontal_vectors,
    top_geometry,
    top_hypotheses,
    top_vectors,
)

FOV90 = math.radians(90.0)
TAU2 = math.radians(2.0)


def _at(origin: tuple[float, float], angle_deg: float, dist: float) -> tuple[float, float]:
    """Top-image point at ``dist`` pixels from ``origin`` in direction ``angle_deg`` (CCW)."""
    a = math.radians(angle_deg)
    return origin[0] + dist * math.cos(a), origin[1] - dist * math.sin(a)


def _vectors(centres, camera: int, theta: float, fov: float = FOV90, tau: float = TAU2):
    """(x, y, index) of the single hypothesis (camera, theta), trimmed to its count."""
    geo = top_geometry(np.asarray(centres, dtype=float), [camera], tau)
    v = top_vectors(geo, np.array([theta]), fov)
    n = int(v.count[0])
    return v.x[0, :n], v.y[0, :n], v.index[0, :n]


# --------------------------------------------------------------------------------------------
# Horizontal view (Eqs. 9-10)


def test_box_centres():
    boxes = np.array([[10.0, 20.0, 4.0, 6.0], [0.0, 0.0, 1.0, 1.0]])
    np.testing.assert_array_equal(box_centres(boxes), [[12.0, 23.0], [0.5, 0.5]])
    assert box_centres(np.zeros((0, 4))).shape == (0, 2)


def test_horizontal_vectors_hand_computed():
    # W = 2688 (the reference width): x = (u - 1344) / 1344 with u the box centre, y = 1 / h.
    boxes = np.array(
        [
            [1816.0, 100.0, 200.0, 400.0],  # u = 1916 -> x = 572 / 1344, h = 400 -> y = 0.0025
            [0.0, 0.0, 100.0, 50.0],  # u = 50   -> x = -1294 / 1344, h = 50  -> y = 0.02
            [1244.0, 10.0, 200.0, 100.0],  # u = 1344 -> x = 0,     h = 100 -> y = 0.01
        ]
    )
    vectors, order = horizontal_vectors(boxes, 2688.0)
    np.testing.assert_array_equal(order, [1, 2, 0])
    np.testing.assert_allclose(
        vectors, [[-1294 / 1344, 0.02], [0.0, 0.01], [572 / 1344, 0.0025]], rtol=1e-15
    )


def test_horizontal_y_is_in_reference_pixels():
    # W = 1344, half the reference width: a box 100 px tall is 200 reference px tall.
    boxes = np.array([[600.0, 0.0, 50.0, 100.0]])
    vectors, _ = horizontal_vectors(boxes, 1344.0)
    np.testing.assert_allclose(vectors[0], [(625 - 672) / 672, 1 / 200], rtol=1e-15)
    assert REFERENCE_SIZE == (2688, 1512)


def test_horizontal_vectors_ties_broken_by_depth():
    # Same centre u, different heights: sorted by y = 1/h, so the taller (nearer) box first.
    boxes = np.array([[100.0, 0.0, 50.0, 100.0], [100.0, 0.0, 50.0, 400.0]])
    vectors, order = horizontal_vectors(boxes, 2688.0)
    np.testing.assert_array_equal(order, [1, 0])
    np.testing.assert_allclose(vectors[:, 1], [1 / 400, 1 / 100])


def test_horizontal_vectors_empty():
    vectors, order = horizontal_vectors(np.zeros((0, 4)), 2688.0)
    assert vectors.shape == (0, 2) and order.shape == (0,)


_hor_box = st.tuples(
    st.integers(0, 1999),
    st.integers(0, 999),
    st.integers(1, 400),
    st.integers(1, 800),
).map(lambda b: (b[0] / 2.0, b[1] / 2.0, b[2] / 2.0, b[3] / 2.0))


@settings(max_examples=60, deadline=None)
@given(boxes=st.lists(_hor_box, min_size=1, max_size=8), data=st.data())
def test_horizontal_vectors_properties(boxes, data):
    boxes = np.asarray(boxes)
    width = 1200.0
    vectors, order = horizontal_vectors(boxes, width)
    # order is a permutation and each row is Eq. 9 of the box it names.
    np.testing.assert_array_equal(np.sort(order), np.arange(len(boxes)))
    u = boxes[order, 0] + boxes[order, 2] / 2
    np.testing.assert_allclose(vectors[:, 0], (u - width / 2) / (width / 2), rtol=1e-12)
    np.testing.assert_allclose(vectors[:, 1], (width / 2688) / boxes[order, 3], rtol=1e-12)
    # Eq. 10: ascending in x (ties by y).
    keys = list(zip(vectors[:, 0], vectors[:, 1], strict=True))
    assert keys == sorted(keys)
    # The result does not depend on the input order.
    perm = np.asarray(data.draw(st.permutations(range(len(boxes)))))
    again, order2 = horizontal_vectors(boxes[perm], width)
    np.testing.assert_array_equal(again, vectors)
    # ... and names boxes with the same centre u and height (fully equal vectors may swap).
    key = np.column_stack([boxes[:, 0] + boxes[:, 2] / 2, boxes[:, 3]])
    np.testing.assert_array_equal(key[perm][order2], key[order])


# --------------------------------------------------------------------------------------------
# Top view (Eqs. 5-8): a hand-made layout around O = (500, 500), theta = 0 (looking towards +u)

O = (500.0, 500.0)  # noqa: E741 (the paper's name for the camera location)


def test_person_straight_ahead():
    x, y, idx = _vectors([O, _at(O, 0.0, 120.0)], camera=0, theta=0.0)
    np.testing.assert_allclose(x, [0.0], atol=1e-15)
    np.testing.assert_allclose(y, [120.0])
    np.testing.assert_array_equal(idx, [1])


@pytest.mark.parametrize(
    ("angle_deg", "expected_x"),
    [
        (30.0, -math.tan(math.radians(30.0)) / math.tan(math.radians(45.0))),  # left: x < 0
        (-30.0, math.tan(math.radians(30.0))),  # right: x > 0
        (10.0, -math.tan(math.radians(10.0))),
    ],
)
def test_person_off_axis(angle_deg, expected_x):
    dist = 100.0
    x, y, _ = _vectors([O, _at(O, angle_deg, dist)], camera=0, theta=0.0)
    np.testing.assert_allclose(x, [expected_x], rtol=1e-12)
    # Eq. 5: y = |OP| sin<OP, V> = |OP| cos(angle from the optical axis).
    np.testing.assert_allclose(y, [dist * math.cos(math.radians(angle_deg))], rtol=1e-12)


@pytest.mark.parametrize("angle_deg", [45.0, -45.0, 90.0, 135.0, 180.0, -120.0])
def test_person_on_the_fov_boundary_or_behind_is_absent(angle_deg):
    # fov 90: the boundary x = -1 / +1 is excluded (|delta| < alpha / 2), and behind is absent.
    x, _, _ = _vectors([O, _at(O, angle_deg, 100.0)], camera=0, theta=0.0)
    assert x.size == 0


def test_exact_45_degree_point_is_excluded_but_44_is_kept():
    centres = [O, (600.0, 400.0), _at(O, 44.0, 100.0)]  # (600, 400) is exactly 45 deg left
    x, _, idx = _vectors(centres, camera=0, theta=0.0)
    np.testing.assert_array_equal(idx, [2])
    np.testing.assert_allclose(x, [-math.tan(math.radians(44.0))], rtol=1e-12)


def test_theta_rotates_the_field_of_view():
    # theta = 90 deg looks up on screen (-v): a person above O is straight ahead, one to the
    # screen right is 90 deg to the camera's right (outside a 90 deg fov).
    centres = [O, (500.0, 300.0), (700.0, 500.0), _at(O, 60.0, 50.0)]
    x, y, idx = _vectors(centres, camera=0, theta=math.pi / 2)
    np.testing.assert_array_equal(idx, [1, 3])
    np.testing.assert_allclose(x, [0.0, math.tan(math.radians(30.0))], atol=1e-12)
    np.testing.assert_allclose(y, [200.0, 50.0 * math.cos(math.radians(30.0))], rtol=1e-12)


def test_full_layout_sorted_by_x():
    centres = [
        _at(O, -30.0, 80.0),  # right
        O,  # camera
        _at(O, 30.0, 100.0),  # left
        _at(O, 180.0, 50.0),  # behind
        _at(O, 0.0, 200.0),  # ahead
    ]
    x, y, idx = _vectors(centres, camera=1, theta=0.0)
    t30 = math.tan(math.radians(30.0))
    np.testing.assert_array_equal(idx, [2, 4, 0])
    np.testing.assert_allclose(x, [-t30, 0.0, t30], atol=1e-12)
    c30 = math.cos(math.radians(30.0))
    np.testing.assert_allclose(y, [100.0 * c30, 200.0, 80.0 * c30], rtol=1e-12)


def test_fov_normalisation_eq7():
    # With fov alpha, x = -tan(delta) / tan(alpha / 2): a person at 20 deg left, fov 60.
    x, _, _ = _vectors([O, _at(O, 20.0, 100.0)], camera=0, theta=0.0, fov=math.radians(60.0))
    np.testing.assert_allclose(x, [-math.tan(math.radians(20.0)) / math.tan(math.radians(30.0))])


# --------------------------------------------------------------------------------------------
# Occlusion (Sec. 3.2.2): within tau of the same direction, the farther one is hidden


def test_occlusion_hides_the_farther_person():
    near, far = _at(O, 1.0, 100.0), _at(O, 0.0, 200.0)  # 1 deg apart < tau = 2 deg
    geo = top_geometry(np.array([O, far, near]), [0], TAU2)
    np.testing.assert_array_equal(geo.visible, [[False, False, True]])
    _, _, idx = _vectors([O, far, near], camera=0, theta=0.0)
    np.testing.assert_array_equal(idx, [2])


def test_occlusion_beyond_tau_keeps_both():
    near, far = _at(O, 3.0, 100.0), _at(O, 0.0, 200.0)  # 3 deg apart > tau = 2 deg
    geo = top_geometry(np.array([O, far, near]), [0], TAU2)
    np.testing.assert_array_equal(geo.visible, [[False, True, True]])
    _, _, idx = _vectors([O, far, near], camera=0, theta=0.0)
    np.testing.assert_array_equal(idx, [2, 1])


def test_occlusion_uses_tau_parameter():
    near, far = _at(O, 3.0, 100.0), _at(O, 0.0, 200.0)
    geo = top_geometry(np.array([O, far, near]), [0], math.radians(4.0))
    np.testing.assert_array_equal(geo.visible, [[False, False, True]])


def test_occlusion_across_the_zero_angle_wraparound():
    # Directions 359.5 and 0.5 degrees are 1 degree apart, not 359.
    near, far = _at(O, 359.5, 100.0), _at(O, 0.5, 300.0)
    geo = top_geometry(np.array([O, near, far]), [0], TAU2)
    np.testing.assert_array_equal(geo.visible, [[False, True, False]])


def test_occlusion_is_per_candidate():
    # Seen from A, B hides C; seen from D (perpendicular), all three are apart.
    a, b, c, d = (0.0, 0.0), (100.0, 0.0), (200.0, 0.0), (150.0, 300.0)
    geo = top_geometry(np.array([a, b, c, d]), [0, 3], TAU2)
    np.testing.assert_array_equal(
        geo.visible, [[False, True, False, True], [True, True, True, False]]
    )


# --------------------------------------------------------------------------------------------
# Property tests against a direct transcription of Eqs. 5-7


def _reference(centres: np.ndarray, camera: int, theta: float, fov: float, tau: float):
    """Sorted (x, y, index) of one hypothesis from Eqs. 5-7 with the right direction V."""
    ou, ov = centres[camera]
    optical = (math.cos(theta), -math.sin(theta))  # image (u, v) of direction theta
    right = (math.sin(theta), math.cos(theta))  # optical axis turned clockwise on screen
    half = fov / 2
    rel = [(u - ou, v - ov) for u, v in centres]
    dist = [math.hypot(du, dv) for du, dv in rel]

    def angle(a, b):
        return math.atan2(abs(a[0] * b[1] - a[1] * b[0]), a[0] * b[0] + a[1] * b[1])

    out = []
    for m, p in enumerate(rel):
        if dist[m] == 0:
            continue
        hidden = any(
            n != m and 0 < dist[n] < dist[m] and angle(p, rel[n]) < tau for n in range(len(rel))
        )
        if hidden or angle(p, optical) >= half:
            continue
        to_right = angle(p, right)  # <OP, V>
        x_hat = 1.0 / math.tan(to_right)  # f cot<OP, V> with f = 1 (Eq. 5)
        x = x_hat / (1.0 / math.tan((math.pi - fov) / 2))  # Eqs. 6-7
        out.append((x, dist[m] * math.sin(to_right), m))
    return sorted(out)


def _layout_is_generic(centres: np.ndarray, fov: float, tau: float, thetas, candidates) -> bool:
    """No person within 1e-6 rad of the fov boundary or of the tau threshold, no ties.

    Exactly on those boundaries the result is decided by rounding, and two people at the very
    same distance within tau of each other have no "farther" one; properties are stated off them.
    """
    for c in candidates:
        d = centres - centres[c]
        dist = np.hypot(d[:, 0], d[:, 1])
        phi = np.arctan2(-d[:, 1], d[:, 0])
        others = dist > 0
        gap = np.abs(np.angle(np.exp(1j * (phi[:, None] - phi[None, :]))))
        pair = others[:, None] & others[None, :] & ~np.eye(len(centres), dtype=bool)
        if (pair & (np.abs(gap - tau) < 1e-6)).any():
            return False
        if (pair & (gap < tau + 1e-6) & (np.abs(dist[:, None] - dist[None, :]) < 1e-9)).any():
            return False
        for theta in thetas:
            delta = np.abs(np.angle(np.exp(1j * (phi - theta))))
            if (others & (np.abs(delta - fov / 2) < 1e-6)).any():
                return False
    return True


_point = st.tuples(st.integers(0, 2000), st.integers(0, 1200)).map(
    lambda p: (p[0] / 2.0, p[1] / 2.0)
)


@st.composite
def _layouts(draw):
    centres = np.asarray(draw(st.lists(_point, min_size=2, max_size=8, unique=True)))
    thetas = np.asarray(
        draw(st.lists(st.floats(0.0, 2 * math.pi, exclude_max=True), min_size=1, max_size=4))
    )
    fov = math.radians(draw(st.floats(20.0, 170.0)))
    tau = math.radians(draw(st.floats(0.5, 10.0)))
    return centres, thetas, fov, tau


@pytest.mark.slow
@settings(max_examples=80, deadline=None)
@given(layout=_layouts())
def test_top_vectors_match_eqs_5_to_7(layout):
    centres, thetas, fov, tau = layout
    candidates = np.arange(len(centres))
    assume(_layout_is_generic(centres, fov, tau, thetas, candidates))
    geo = top_geometry(centres, candidates, tau)
    vec = top_vectors(geo, thetas, fov)
    hyp = top_hypotheses(geo, thetas, fov)
    assert vec.x.shape[0] == len(candidates) * len(thetas)
    np.testing.assert_array_equal(hyp.count, vec.count)
    for c in candidates:
        for t, theta in enumerate(thetas):
            b = c * len(thetas) + t  # candidate-major rows
            n = int(vec.count[b])
            ref = _reference(centres, c, theta, fov, tau)
            # |K| = the number of (visible) people inside the field of view.
            assert n == len(ref)
            x, y, idx = vec.x[b, :n], vec.y[b, :n], vec.index[b, :n]
            np.testing.assert_allclose(x, [r[0] for r in ref], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(y, [r[1] for r in ref], rtol=1e-9, atol=1e-9)
            np.testing.assert_array_equal(idx, [r[2] for r in ref])
            # Eq. 8: ascending x, strictly inside (-1, 1), depths in front of the camera.
            assert np.all(np.diff(x) >= 0)
            assert np.all(np.abs(x) < 1.0)
            assert np.all(y > 0)
            assert c not in idx
            # Padding.
            assert np.all(np.isinf(vec.x[b, n:])) and np.all(vec.index[b, n:] == -1)
            # The unsorted hypotheses hold the same values.
            finite = np.isfinite(hyp.x[b])
            np.testing.assert_array_equal(np.sort(hyp.x[b, finite]), x)


@settings(max_examples=60, deadline=None)
@given(layout=_layouts(), data=st.data())
def test_top_vectors_do_not_depend_on_box_order(layout, data):
    centres, thetas, fov, tau = layout
    n = len(centres)
    candidates = np.arange(n)
    assume(_layout_is_generic(centres, fov, tau, thetas, candidates))
    perm = np.asarray(data.draw(st.permutations(range(n))))  # new box k is old box perm[k]
    inverse = np.argsort(perm)
    base = top_vectors(top_geometry(centres, candidates, tau), thetas, fov)
    # Same physical candidates, in the same order, addressed by their new indices.
    moved = top_vectors(top_geometry(centres[perm], inverse[candidates], tau), thetas, fov)
    np.testing.assert_array_equal(moved.count, base.count)
    np.testing.assert_array_equal(moved.x, base.x)
    np.testing.assert_array_equal(moved.y, base.y)
    mapped = np.where(moved.index >= 0, perm[moved.index], -1)
    np.testing.assert_array_equal(mapped, base.index)


@settings(max_examples=40, deadline=None)
@given(layout=_layouts(), data=st.data())
def test_take_equals_top_vectors_rows(layout, data):
    centres, thetas, fov, tau = layout
    geo = top_geometry(centres, np.arange(len(centres)), tau)
    hyp = top_hypotheses(geo, thetas, fov)
    full = top_vectors(geo, thetas, fov)
    n_rows = hyp.x.shape[0]
    rows = np.asarray(data.draw(st.lists(st.integers(0, n_rows - 1), min_size=1, max_size=n_rows)))
    part = hyp.take(rows)
    width = part.x.shape[1]
    assert width == int(full.count[rows].max())
    np.testing.assert_array_equal(part.count, full.count[rows])
    np.testing.assert_array_equal(part.x, full.x[rows, :width])
    np.testing.assert_array_equal(part.y, full.y[rows, :width])
    np.testing.assert_array_equal(part.index, full.index[rows, :width])


@settings(max_examples=60, deadline=None)
@given(layout=_layouts())
def test_compiled_vectors_are_bit_identical_to_the_numpy_forms(layout):
    # The search's kernels (cues/search_kernels.py) compute Eqs. 5-8 per element; they must
    # give exactly the vectorised numpy values, so that features and figures do not move.
    centres, thetas, fov, tau = layout
    geo = top_geometry(centres, np.arange(len(centres)), tau)
    out = {}
    for mode in ("compiled", "numpy"):
        with kernel_choice.forced(mode):
            hyp = top_hypotheses(geo, thetas, fov)
            rows = np.arange(hyp.x.shape[0])[::-1]  # any order of rows
            out[mode] = (hyp, hyp.take(rows))
    (hyp, vec), (ref, ref_vec) = out["compiled"], out["numpy"]
    for name in ("x", "delta", "count"):
        np.testing.assert_array_equal(getattr(hyp, name), getattr(ref, name))
    for name in ("x", "y", "index", "count"):
        np.testing.assert_array_equal(getattr(vec, name), getattr(ref_vec, name))


_EDGES = [0.0, -0.0, 2 * math.pi, -2 * math.pi, 4 * math.pi, -1e-300, 1e-300, -5e-17,
          math.nextafter(2 * math.pi, 0.0), math.nextafter(4 * math.pi, 0.0), math.pi, -math.pi,
          1e300, -1e300, math.inf, -math.inf, math.nan]


@settings(max_examples=300, deadline=None)
@given(a=st.one_of(st.sampled_from(_EDGES), st.floats(-15.0, 15.0), st.floats()))
def test_the_kernels_mod_of_two_pi_is_numpys_to_the_bit(a):
    # The search's table and the learned features wrap angles with it instead of numba's mod
    # (three times faster): every bit and sign as numpy's, in and out of its fast range.
    kernels = pytest.importorskip("xvmatch.cues.search_kernels")
    got, want = kernels._mod_two_pi(a), float(np.mod(a, 2 * np.pi))
    assert np.float64(got).tobytes() == np.float64(want).tobytes() or (got != got and
                                                                      want != want)


def test_candidate_itself_and_coincident_people_are_not_visible():
    # A person standing exactly at O has no direction: absent, as O itself.
    geo = top_geometry(np.array([O, O, _at(O, 0.0, 10.0)]), [0], TAU2)
    np.testing.assert_array_equal(geo.visible, [[False, False, True]])


def test_equidistant_people_within_tau_both_stay_whatever_the_box_order():
    """Only a strictly nearer person hides another, so visibility never depends on box order."""
    a = np.array([[0.0, 0.0], [100.0, 1.0], [100.0, -1.0]])
    b = a[[0, 2, 1]]
    np.testing.assert_array_equal(top_geometry(a, [0]).visible, [[False, True, True]])
    np.testing.assert_array_equal(top_geometry(b, [0]).visible, [[False, True, True]])


def test_occlusion_in_blocks_of_candidates_is_the_same(monkeypatch):
    # A crowd is tested in blocks of candidates to bound memory; any block size gives the same
    # visibility, angles and distances.
    from xvmatch.cues import spatial_vectors

    rng = np.random.default_rng(3)
    centres = rng.uniform(0.0, 300.0, size=(40, 2))
    whole = top_geometry(centres, np.arange(40))
    monkeypatch.setattr(spatial_vectors, "OCCLUSION_BLOCK", 3 * 40 * 40)  # 3 per block
    parts = top_geometry(centres, np.arange(40))
    assert not whole.visible.all()  # some people are hidden: the test can fail
    for name in ("phi", "dist", "visible"):
        np.testing.assert_array_equal(getattr(parts, name), getattr(whole, name))
