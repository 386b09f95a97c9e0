"""Parsing the JSON of a user's file with every failure one line: the file reader's own error.

``json.loads`` fails in three ways on hostile or broken text: a syntax error
(``JSONDecodeError``, with a line and column), nesting deeper than Python's recursion limit
(``RecursionError``, e.g. 100000 ``[``) and a number too long to convert (``ValueError``).
:func:`parse_json` turns all three into the caller's ``ValueError`` subclass with one line
naming the file, so a reader never lets a traceback through. It lives in ``core/`` (the
lowest layer) so that every reader may use it.
"""

from __future__ import annotations

import json

__all__ = ["json_problem", "parse_json"]


def json_problem(exc: BaseException) -> str:
    """What went wrong parsing JSON, in one line (no file name): ``"line L column C: ..."``."""
    if isinstance(exc, json.JSONDecodeError):
        return f"line {exc.lineno} column {exc.colno}: not valid JSON ({exc.msg})"
    if isinstance(exc, RecursionError):
        return "not valid JSON here (nested too deeply: more levels than the reader follows)"
    lines = [line for line in str(exc).splitlines() if line.strip()]
    return f"not valid JSON here ({lines[0] if lines else type(exc).__name__})"


def parse_json(text: str | bytes, where: str, error: type[ValueError] = ValueError) -> object:
    """``json.loads(text)``, any failure raised as ``error("WHERE: PROBLEM")`` in one line.

    Args:
        text: the file's text.
        where: the file, named first in the message.
        error: the exception class to raise (the reader's own, a ``ValueError``).

    Raises:
        error: a syntax error (with its line and column), nesting too deep, or a number too long.
    """
    try:
        return json.loads(text)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise error(f"{where}: {json_problem(exc)}") from None
