"""Student text shown as text: in the Markdown feedback, the HTML class report and the grader's terminal.

Students choose their file names, what their code raises and prints, their cells' first lines and their
headings, and all of that reaches the gradebook's messages, the feedback files and the class report. There it
must read as what it is, never act:

* :func:`visible_controls` shows control characters as ``[U+202E]``: a right-to-left override (U+202E) and
  the other bidirectional controls would reverse the text after them, a terminal escape (ESC) would drive
  the instructor's terminal, a line break would start a Markdown block of the student's making;
* :func:`md_code` puts text in a Markdown code span whose backtick fence is longer than any run of backticks
  inside (CommonMark), so ``<script>``, ``<img src=…>``, ``[x](javascript:…)``, ``**Score: 8 / 8**`` and an
  unclosed ``<!--`` are shown literally by any CommonMark or GitHub renderer;
* :func:`clip` bounds how much of it is shown.

The HTML report escapes with :func:`html.escape` after :func:`visible_controls`.
"""

from __future__ import annotations

import re

#: bidirectional controls (embeddings, overrides, isolates, marks) and the line and paragraph separators
BIDI = "\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069\u200e\u200f\u061c\u2028\u2029"
_CONTROLS = [chr(c) for c in [*range(0x20), *range(0x7F, 0xA0)]] + list(BIDI)  # Unicode's Cc, and BIDI
_SHOWN = str.maketrans({c: f"[U+{ord(c):04X}]" for c in _CONTROLS})
_ONE_LINE = str.maketrans({**{c: f"[U+{ord(c):04X}]" for c in _CONTROLS}, "\t": " ", "\n": " ", "\r": " "})
_LINES = str.maketrans({**{c: f"[U+{ord(c):04X}]" for c in _CONTROLS}, "\t": "\t", "\n": "\n"})
_BACKTICKS = re.compile("`+")


def visible_controls(text: str, lines: bool = False) -> str:
    """``text`` with every control character shown as ``[U+XXXX]``; tabs and line breaks become spaces, or
    (``lines``) tabs and ``\\n`` are kept."""
    return text.translate(_LINES if lines else _ONE_LINE)


def clip(text: str, limit: int) -> str:
    """At most ``limit`` characters of ``text``, the last one ``…`` when it was cut."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


def md_code(text: str) -> str:
    """``text`` as one Markdown code span, shown literally (see the module doc), on one line."""
    text = visible_controls(text)
    fence = "`" * (max(map(len, _BACKTICKS.findall(text)), default=0) + 1)
    # CommonMark strips one space from each end when both ends have one: pad so that what is left is ``text``
    if text[:1] in ("`", " ") or text[-1:] in ("`", " ") or not text:
        text = f" {text} "
    return f"{fence}{text}{fence}"
