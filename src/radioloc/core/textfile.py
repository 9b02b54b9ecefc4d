"""Reading users' text files: one decoder for every reader (CSV, JSON).

A file is UTF-8, with or without a byte-order mark, or UTF-16 with its byte-order mark
(as some spreadsheet programs save "Unicode text"). Anything else (Latin-1, a stray byte)
is refused with the line of the first byte that is not UTF-8, so a user can find it.
"""

from __future__ import annotations

import codecs
import json
from pathlib import Path
from typing import Any

from radioloc.core.errors import InputError


def decode_text(raw: bytes, path: Path | str) -> str:
    """The text of a file's bytes.

    Parameters
    ----------
    raw : bytes
        The file's content.
    path : path-like
        For the message.

    Returns
    -------
    str
        Without a byte-order mark.

    Raises
    ------
    InputError
        Bytes that are not UTF-8 (nor UTF-16 with a byte-order mark), naming the line of the
        first bad byte and its value.
    """
    if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError as exc:
            line = raw[:exc.start].decode("utf-16", "replace").count("\n") + 1
            raise InputError(f"{path}: line {line}: not valid UTF-16 text "
                             f"(it starts with a UTF-16 byte-order mark)") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise InputError(f"{path}: line {line}: not UTF-8 text (byte 0x{raw[exc.start]:02x}; "
                         "save the file as UTF-8)") from None


def read_text(path: Path | str, what: str) -> str:
    """A user's text file, decoded by :func:`decode_text`.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is ("calibration", "model"), for the message.

    Returns
    -------
    str

    Raises
    ------
    InputError
        Missing, a folder, unreadable, or not UTF-8/UTF-16 text.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{what} file {path}: not found")
    if path.is_dir():
        raise InputError(f"{what} file {path}: is a folder, not a file")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{what} file {path}: cannot read ({exc.strerror or exc})") from None
    return decode_text(raw, path)


def read_json_object(path: Path | str, what: str) -> dict[str, Any]:
    """A JSON file whose top level is an object.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for the message.

    Returns
    -------
    dict

    Raises
    ------
    InputError
        Not readable text (:func:`read_text`), not JSON (naming the line), nested beyond
        Python's recursion limit, or a top level that is not an object (``null``, a string,
        a list).
    """
    text = read_text(path, what)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{what} file {path}: line {exc.lineno}: not valid JSON "
                         f"({exc.msg})") from None
    except RecursionError:
        raise InputError(f"{what} file {path}: JSON nested too deeply to be a {what}") from None
    if not isinstance(data, dict):
        kind = "null" if data is None else type(data).__name__
        raise InputError(f"{what} file {path}: expected a JSON object ({{\"key\": ...}}), got "
                         f"{kind}")
    return data
