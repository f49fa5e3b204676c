"""The one way a name or a number reaches generated C (``chain.h``, ``variables.h/.c``).

A URDF is a user's file, and what it names (the robot, its joints and links) is data: none
of it may become C code. So nothing here copies text into C as it is. A name becomes a
string literal in which every byte outside printable ASCII, and each of ``"``, ``\\`` and
``?`` (a trigraph's first character), is written as a three-digit octal escape: the
compiler reads back exactly the name's UTF-8 bytes, whatever they are (a comment closer,
a newline, a trigraph, a quote). No C identifier is made from a user's name (the model
identifier and every macro are the project's own). A number is formatted by us from a
float, and a NaN is refused, not written. Names never go into comments: generated
comments are fixed text.

:func:`check_generated` states the grammar the generated sources keep, and the tests hold
every generated file to it (tests/test_generated_c.py).
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Iterable

# The bytes a string literal keeps as they are: printable ASCII but the quote, the
# backslash and the question mark (so that no "??/" trigraph can form).
_PLAIN = frozenset(range(0x20, 0x7F)) - {ord('"'), ord("\\"), ord("?")}
# A string literal as string_literal writes it: kept bytes and three-digit octal escapes.
_LITERAL = re.compile('"(?:[' + "".join(re.escape(chr(b)) for b in sorted(_PLAIN))
                      + r']|\\[0-7]{3})*"')


def string_literal(text: str) -> str:
    """``text`` as a C string literal whose value is its UTF-8 bytes, escaped as above."""
    return '"' + "".join(chr(b) if b in _PLAIN else f"\\{b:03o}"
                         for b in text.encode("utf-8", "surrogatepass")) + '"'


def number(x: float) -> str:
    """A finite number, or +-INFINITY, as C; a NaN (or a value that is not a number) is
    refused with ValueError."""
    x = float(x)
    if math.isnan(x):
        raise ValueError("a NaN cannot be written into generated C")
    if math.isinf(x):
        return "INFINITY" if x > 0 else "-INFINITY"
    return repr(x)


def integer(value) -> str:
    """A whole number as C (a float is refused: operator.index)."""
    return str(operator.index(value))


def array(values: Iterable) -> str:
    """A (nested) brace initialiser of numbers, row by row."""
    import numpy as np

    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        return "{" + ", ".join(number(x) for x in values) + "}"
    return "{" + ", ".join(array(row) for row in values) + "}"


def skeleton(source: str) -> str:
    """``source`` with every string literal of :func:`string_literal`'s form replaced by
    ``""``: the code that names cannot reach (tests compare it between two chains)."""
    return _LITERAL.sub('""', source)


def check_generated(source: str) -> None:
    """Raise ValueError unless ``source`` keeps the grammar of generated C: outside string
    literals of :func:`string_literal`'s form, only printable ASCII and newlines, with no
    ``?`` (no trigraph), no backslash (no line splice or escape) and no other quote."""
    for line_number, line in enumerate(skeleton(source).split("\n"), 1):
        bad = [ch for ch in line.replace('""', "") if not " " <= ch <= "~" or ch in '?\\"']
        if bad:
            raise ValueError(f"generated line {line_number} holds {bad[0]!r} outside a "
                             f"string literal: {line!r}")
