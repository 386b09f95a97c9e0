"""Typed fields of the records read from users' files (bundle manifests, matcher files): one
check, one wording, whatever the file."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["typed_field"]


def typed_field(record: object, key: str, kinds: type | tuple[type, ...], where: str, *,
                error: type[ValueError] = ValueError, document: str = "record",
                prefix: str = "") -> Any:
    """``record[key]`` checked to be one of ``kinds`` (a bool is no number here).

    Args:
        record: the mapping read from the file.
        key: the field.
        kinds: the accepted types (``type(None)`` for null).
        where: the file, named first in the message.
        error: the reader's own ``ValueError`` subclass.
        document: what the file is called in the message ("manifest", "matcher file").
        prefix: the field's path inside the record, e.g. ``"appearance."``.

    Raises:
        error: the field is absent or of another type, in one line naming file and field.
    """
    name = f"{prefix}{key}"
    if not isinstance(record, Mapping) or key not in record:
        raise error(f"{where}: {document} lacks the field {name!r}")
    kinds = kinds if isinstance(kinds, tuple) else (kinds,)
    value = record[key]
    if not isinstance(value, kinds) or (isinstance(value, bool) and bool not in kinds):
        wanted = " or ".join("null" if k is type(None) else k.__name__ for k in kinds)
        raise error(f"{where}: {document} field {name!r} must be {wanted}, got "
                    f"{type(value).__name__} {value!r:.60}")
    return value
