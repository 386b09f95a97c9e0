import numpy as np
import pytest

from xvmatch.core.array_checks import as_boxes, as_points


def test_as_boxes_accepts_empty_and_valid():
    assert as_boxes([]).shape == (0, 4)
    np.testing.assert_array_equal(as_boxes([[1, 2, 3, 4]]), [[1.0, 2.0, 3.0, 4.0]])
    # Boxes may lie outside the image (negative corner), only sizes must be >= 0.
    assert as_boxes([[-50, -20, 3, 4]]).shape == (1, 4)


@pytest.mark.parametrize(
    ("boxes", "message"),
    [
        ([[1, 2, 3]], r"shape \(N, 4\)"),
        ([[1, 2, np.nan, 4]], "NaN or inf"),
        ([[1, 2, -3, 4]], "negative width or height"),
    ],
)
def test_as_boxes_rejects_bad_input_naming_the_argument(boxes, message):
    with pytest.raises(ValueError, match=message) as info:
        as_boxes(boxes, name="top_boxes")
    assert "top_boxes" in str(info.value)


def test_as_points_shapes_and_finiteness():
    assert as_points([], 2, "pixels").shape == (0, 2)
    assert as_points(np.zeros((3, 5, 3)), 3, "points").shape == (3, 5, 3)
    with pytest.raises(ValueError, match=r"pixels must have shape \(\.\.\., 2\)"):
        as_points([1.0, 2.0, 3.0], 2, "pixels")
    with pytest.raises(ValueError, match="NaN"):
        as_points([[np.inf, 0.0]], 2, "pixels", finite=True)
    as_points([[np.inf, 0.0]], 2, "pixels")  # finiteness is opt-in
