import argparse

import pytest

from xvmatch.cli_types import image_size, int_at_least, non_negative_int, positive_int


def test_integers_respect_their_minimum():
    assert positive_int("3") == 3 and non_negative_int("0") == 0 and int_at_least(5)("5") == 5
    for convert, text, message in (
        (positive_int, "0", "positive integer"),
        (positive_int, "x", "positive integer"),
        (non_negative_int, "-1", "integer >= 0"),
        (int_at_least(5), "4", "integer >= 5"),
    ):
        with pytest.raises(argparse.ArgumentTypeError, match=message):
            convert(text)


def test_image_size_parses_and_bounds():
    assert image_size()("2688x1512") == (2688, 1512)
    assert image_size(8)("640X360") == (640, 360)
    with pytest.raises(argparse.ArgumentTypeError, match="WIDTHxHEIGHT"):
        image_size()("12")
    with pytest.raises(argparse.ArgumentTypeError, match="at least 8x8"):
        image_size(8)("4x4")
