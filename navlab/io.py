"""The one way navlab reads a user's file: bytes -> text -> (optionally) JSON, or a clear error.

Every file navlab reads (a recording, a generic CSV, a ``--config`` file, a configuration
uploaded in the browser) passes through :func:`read_text` / :func:`decode_text`, and every JSON
through :func:`parse_json`, so the rules are the same everywhere:

* a UTF-8 byte-order mark (written by spreadsheet programs: "CSV UTF-8") is removed;
* UTF-16/32 text, binary files and text that is not UTF-8 are refused with the file's name and
  what to do (save it as UTF-8 text);
* a file larger than the stated limit is refused before it is read;
* JSON nested deeper than :data:`MAX_JSON_DEPTH` or larger than :data:`MAX_JSON_BYTES` is refused
  before it is parsed (Python's parser would raise ``RecursionError`` on 100 000 nested ``[``).

Each error is a :class:`navlab.errors.NavlabError`: the CLI prints it as one line and exits with
status 2; the app shows it as a message.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from navlab.errors import NavlabError

#: Largest text file read (bytes): far above any recording navlab is meant for (the bundled
#: 100 Hz IMU file of 549 s is 2.5 MB), small enough to refuse a wrong file before reading it.
MAX_TEXT_BYTES = 512 * 2**20
#: Largest JSON document (bytes): a configuration is a few kB.
MAX_JSON_BYTES = 2**20
#: Deepest nesting of JSON arrays/objects accepted (a configuration nests 3 levels).
MAX_JSON_DEPTH = 32

_BOMS = (
    (b"\xef\xbb\xbf", None),  # UTF-8: stripped
    (b"\xff\xfe\x00\x00", "UTF-32"),
    (b"\x00\x00\xfe\xff", "UTF-32"),
    (b"\xff\xfe", "UTF-16"),
    (b"\xfe\xff", "UTF-16"),
)
_SAVE_AS = "save it as UTF-8 text (in a spreadsheet program: 'CSV UTF-8'; in an editor: encoding UTF-8)"


def decode_text(raw: bytes, name: str) -> str:
    """Bytes of a text file -> str (UTF-8, BOM removed); NavlabError naming ``name`` otherwise.

    Parameters
    ----------
    raw : bytes
        The file's content.
    name : str
        How the user knows the file (a path, "uploaded imu.csv", "--config spec.json").
    """
    for bom, enc in _BOMS:
        if raw.startswith(bom):
            if enc is None:
                raw = raw[len(bom) :]
                break
            raise NavlabError(f"{name}: the file is {enc} text, not UTF-8; {_SAVE_AS}")
    if b"\x00" in raw[:65536]:
        raise NavlabError(
            f"{name}: this is a binary file, not text; give the text (CSV/JSON) file itself, not a "
            "spreadsheet workbook, archive or image"
        )
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise NavlabError(
            f"{name}: line {line} is not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start}); "
            f"{_SAVE_AS}"
        ) from None


def read_text(path: str | os.PathLike, name: str | None = None, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """Read a text file through :func:`decode_text`; NavlabError if missing, too large or not text.

    Parameters
    ----------
    path : path of the file.
    name : how to name the file in messages (default: the path).
    max_bytes : largest size accepted.
    """
    p = Path(path)
    label = name or str(p)
    if p.is_dir():
        raise NavlabError(f"{label}: cannot read it (a folder, not a file); give the file inside it")
    if not p.is_file():
        raise NavlabError(f"{label}: cannot read it (file not found); check the path")
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise NavlabError(
                f"{label}: the file is {size / 2**20:.1f} MB, more than the {max_bytes / 2**20:g} MB "
                "navlab reads; give a shorter file (cut the recording)"
            )
        raw = p.read_bytes()
    except OSError as exc:
        raise NavlabError(f"{label}: cannot read it ({exc.strerror})") from None
    return decode_text(raw, label)


def json_depth(text: str | bytes) -> int:
    """Deepest nesting of ``[``/``{`` in a JSON text (brackets inside strings do not count).

    Linear in the length (vectorised): a quote is a string delimiter unless an odd number of
    backslashes precedes it; brackets between an opening and a closing delimiter are text.
    """
    raw = text.encode("utf-8", "surrogatepass") if isinstance(text, str) else text
    c = np.frombuffer(raw, dtype=np.uint8)
    if c.size == 0:
        return 0
    bs = c == ord("\\")
    cs = np.cumsum(bs)
    run = cs - np.maximum.accumulate(np.where(bs, 0, cs))  # backslashes ending at i
    before = np.r_[0, run[:-1]]
    delim = (c == ord('"')) & (before % 2 == 0)
    in_string = (np.cumsum(delim) % 2 == 1) | delim
    step = np.isin(c, (ord("["), ord("{"))).astype(np.int64) - np.isin(c, (ord("]"), ord("}")))
    return int(np.cumsum(np.where(in_string, 0, step)).max(initial=0))


def parse_json(
    text: str | bytes,
    name: str = "the configuration",
    max_bytes: int = MAX_JSON_BYTES,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """JSON text (or bytes) -> Python value; NavlabError for too large, too deep or invalid JSON."""
    if isinstance(text, bytes):
        text = decode_text(text, name)
    elif not isinstance(text, str):
        raise NavlabError(f"{name} must be JSON text (str or bytes), got {type(text).__name__}")
    elif text.startswith("\ufeff"):
        text = text[1:]
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > max_bytes:
        raise NavlabError(
            f"{name} is {size / 1024:.0f} kB of JSON, more than the {max_bytes / 1024:.0f} kB a navlab "
            "configuration may have; give a configuration file (e.g. one written by --save-spec)"
        )
    depth = json_depth(text)
    if depth > max_depth:
        raise NavlabError(
            f"{name} nests JSON arrays/objects {depth} levels deep (at most {max_depth}); it is not a "
            "navlab configuration — give one written by --save-spec or the app's download"
        )
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise NavlabError(
            f"{name} is not valid JSON (line {exc.lineno}, column {exc.colno}: {exc.msg})"
        ) from None
    except (ValueError, RecursionError) as exc:  # e.g. an integer of more than 4300 digits
        raise NavlabError(f"{name} is not a usable JSON document ({str(exc)[:120]})") from None


__all__ = [
    "MAX_JSON_BYTES",
    "MAX_JSON_DEPTH",
    "MAX_TEXT_BYTES",
    "decode_text",
    "json_depth",
    "parse_json",
    "read_text",
]
