"""Documents nested deeper than a parser can follow: one clear error naming the file, never a RecursionError.

Python's ``json`` and ``tomllib`` parsers recurse once per level of ``[``/``{`` (or ``[`` / inline table): a file
of 100 000 opening brackets, damaged or hostile, raises :class:`RecursionError` from deep inside the parser. The
readers of model files, sidecars, mappings, study files and reports parse through :func:`loads_json` and
:func:`loads_toml` (or catch :class:`RecursionError` themselves and raise :func:`too_deep`), and ``udrobot-ctrl``
turns any RecursionError left into a one-line error naming the file it was reading.
"""
from __future__ import annotations

import json
import sys


class NestingError(ValueError):
    """A document nested too deeply to be read; the message names the file."""


def too_deep(source, kind: str = "JSON") -> NestingError:
    """The error for ``source`` (a file name, for the message) whose ``kind`` document nests too deeply."""
    return NestingError(f"{source}: {kind} nested too deeply to read (over about {sys.getrecursionlimit()} levels of "
                        f"brackets or tables; no valid input nests so deep): a damaged or wrong file")


def loads_json(text: str, source, **kwargs):
    """``json.loads(text)``; a document too deep for the parser raises :class:`NestingError` naming ``source``."""
    try:
        return json.loads(text, **kwargs)
    except RecursionError:
        raise too_deep(source, "JSON") from None


def loads_toml(text: str, source):
    """``tomllib.loads(text)``; a document too deep for the parser raises :class:`NestingError` naming
    ``source``."""
    import tomllib

    try:
        return tomllib.loads(text)
    except RecursionError:
        raise too_deep(source, "TOML") from None


def unique_keys(source):
    """An ``object_pairs_hook`` for :func:`json.loads` that refuses a key given twice in one object (``json`` keeps
    the last silently: a second ``"effects"`` would drop the first list), naming ``source`` and the key."""
    def hook(pairs):
        out = {}
        for key, value in pairs:
            if key in out:
                raise ValueError(f"{source}: key {key!r} given twice in one JSON object; expected each key once "
                                 f"(which one was meant is not known)")
            out[key] = value
        return out
    return hook
