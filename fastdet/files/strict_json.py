"""Strict JSON (RFC 8259) for every document fastdet writes, that any parser reads.

Python's :func:`json.dumps` writes ``NaN``/``Infinity`` (not JSON) and a file
name that is not UTF-8 (held by Python with each odd byte as a lone
surrogate, ``surrogateescape``) as a lone-surrogate escape ``"\\udcff"``,
which strict parsers refuse (Rust's serde_json) or replace (Go, jq).  The
rule here:

* **Numbers**: never ``NaN`` or ``Infinity``.  :func:`dumps` passes
  ``allow_nan=False``; a writer whose format documents ``null`` for a
  figure without a value (``fastdet eval --json``, a manifest's ``fps``, a
  model's informational training report) passes ``nonfinite="null"`` and
  such a number is written ``null``; elsewhere the numbers are finite by
  construction, and a non-finite one is a bug that raises ``ValueError``.
* **Names that are not UTF-8**: a string that does not encode to UTF-8 is
  written as valid text with each odd byte shown as ``\\xff`` (the
  :func:`display_text`, as the batch's table and report show it); when it is
  the value of an object's field ``"k"``, the exact bytes go beside it, in
  ``"k_bytes"``, standard base64 (RFC 4648), present only for such a name.
  ``os.fsdecode(base64.b64decode(record["k_bytes"]))`` gives Python's
  ``str`` of the name back (:func:`restore_names` does it for a whole
  document), and ``base64.b64decode`` alone the bytes.  A name that is valid
  UTF-8 is written exactly as before, and no ``_bytes`` field appears.
  Object keys (an image's name as a key of ``eval --json``'s ``images``) and
  list items have no field beside them: they are written as display text only.
"""

from __future__ import annotations

import base64
import binascii
import json
import math
import os

#: Suffix of the field that holds the exact bytes of a name that is not UTF-8.
BYTES_SUFFIX = "_bytes"


def is_utf8(text):
    """Whether ``text`` encodes to UTF-8 (no lone surrogate)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def display_text(text):
    """``text`` as valid Unicode: the odd bytes of a name that is not UTF-8 as ``\\xff``.

    A surrogate no file name decodes to (from an edited file) shows as ``\\udcff``.
    """
    if is_utf8(text):
        return text
    try:
        raw = os.fsencode(text)
    except UnicodeEncodeError:
        raw = text.encode("utf-8", "backslashreplace")
    return raw.decode("utf-8", "backslashreplace")


def name_bytes(text):
    """The base64 of the bytes of a name that is not UTF-8, or ``None`` (valid UTF-8, or
    a surrogate no file name decodes to: there are no bytes to give)."""
    if is_utf8(text):
        return None
    try:
        return base64.b64encode(os.fsencode(text)).decode("ascii")
    except UnicodeEncodeError:
        return None


def strict_value(value, nonfinite="error"):
    """``value`` (dicts, lists, tuples, strings, numbers, ``None``) ready for strict JSON.

    Parameters
    ----------
    value : object
    nonfinite : {'error', 'null'}
        What a ``NaN`` or infinite float becomes: a ``ValueError``, or ``None``.
    """
    if isinstance(value, float):
        if math.isfinite(value):
            return value
        if nonfinite == "null":
            return None
        raise ValueError(f"{value!r} is not a JSON number")
    if isinstance(value, str):
        return display_text(value)
    if isinstance(value, dict):
        out = {}
        for key, item in value.items():
            key = display_text(key) if isinstance(key, str) else key
            out[key] = strict_value(item, nonfinite)
        for key, item in value.items():
            if isinstance(key, str) and isinstance(item, str):
                raw = name_bytes(item)
                field = display_text(key) + BYTES_SUFFIX
                if raw is not None and field not in out:
                    out[field] = raw
        return out
    if isinstance(value, (list, tuple)):
        return [strict_value(item, nonfinite) for item in value]
    return value


def dumps(value, nonfinite="error", **options):
    """:func:`json.dumps` of :func:`strict_value`, with ``allow_nan=False``.

    ``options`` go to :func:`json.dumps` (``sort_keys``, ``separators``).  The
    text is ASCII (``ensure_ascii`` as by default), so it is valid UTF-8 too.
    """
    return json.dumps(strict_value(value, nonfinite), allow_nan=False, **options)


def restore_names(value):
    """A parsed document with each ``"k"``/``"k_bytes"`` pair back to Python's ``str``
    of the name (``surrogateescape``), as fastdet held it before writing.

    Documents written before the ``_bytes`` fields (with ``"\\udcff"`` escapes,
    which :func:`json.loads` reads to the same ``str``) pass through unchanged;
    a ``_bytes`` field that is not base64 is left as it is.
    """
    if isinstance(value, list):
        return [restore_names(item) for item in value]
    if not isinstance(value, dict):
        return value
    out = {key: restore_names(item) for key, item in value.items()}
    for key in list(out):
        field = f"{key}{BYTES_SUFFIX}" if isinstance(key, str) else None
        if (field is None or key not in out or not isinstance(out[key], str)
                or not isinstance(out.get(field), str)):
            continue
        try:
            name = os.fsdecode(base64.b64decode(out[field], validate=True))
        except (binascii.Error, ValueError):
            continue
        if display_text(name) == out[key]:   # the pair this module writes, not a user's field
            out[key] = name
            del out[field]
    return out
