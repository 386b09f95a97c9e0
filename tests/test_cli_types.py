import argparse

import pytest

from xvmatch.commands._types import image_size, int_at_least, non_negative_int, positive_int


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


def test_int_in_gives_the_range_and_why():
    from xvmatch.commands._types import int_in

    convert = int_in(1, 64, "cores")
    assert convert("1") == 1 and convert("64") == 64
    for text in ("0", "65", "x", "1.5", "", "9" * 5000):
        with pytest.raises(argparse.ArgumentTypeError,
                           match=r"^expected a positive integer in \[1, 64\] \(cores\), got "):
            convert(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r"an integer in \[-2\*\*53, 2\*\*53\]"):
        int_in(-(2**53), 2**53)(str(2**53 + 1))
    with pytest.raises(argparse.ArgumentTypeError, match=r"^expected an integer <= 9, got '10'"):
        int_in(None, 9)("10")
    assert int_in(None, 9)("-5") == -5


def test_float_in_refuses_non_finite_and_open_bounds():
    from xvmatch.commands._types import float_in

    dtheta = float_in(0.01, 360, "the search tries 360 / dtheta orientations")
    assert dtheta("0.01") == 0.01 and dtheta("360") == 360.0
    for text in ("1e-6", "361", "nan", "inf", "-inf", "abc", ""):
        with pytest.raises(argparse.ArgumentTypeError,
                           match=r"^expected a number in \[0.01, 360\] \(the search tries"):
            dtheta(text)
    fov = float_in(0, 180, low_open=True, high_open=True)
    assert fov("90") == 90.0
    for text in ("0", "180"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"in \(0, 180\), got"):
            fov(text)
    rho = float_in(None, 1e6)
    assert rho("0.5") == 0.5
    for text in ("2e6", "nan", "-inf"):
        with pytest.raises(argparse.ArgumentTypeError, match=r"a finite number <= 1e6, got"):
            rho(text)


def test_image_size_maximum_and_offsets():
    from xvmatch.commands._types import offset_value

    convert = image_size(8, 8192, "memory")
    assert convert("8192x8") == (8192, 8)
    with pytest.raises(argparse.ArgumentTypeError,
                       match=r"at least 8x8 and at most 8192x8192 \(memory\), got '8193x8'"):
        convert("8193x8")
    assert offset_value("auto") == "auto" and offset_value("-100000") == -100000
    with pytest.raises(argparse.ArgumentTypeError, match=r"\[-100000, 100000\]"):
        offset_value("100001")
