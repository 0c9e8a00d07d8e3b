"""The class report: a gradebook → one self-contained HTML page the instructor looks at.

    kfkit report gradebook.csv            # → gradebook_report.html beside it

The page holds everything inline (SVG charts, a ``<style>`` block, no script, no font, no link to
another site; its Content-Security-Policy forbids loading anything), so it opens offline and can be
mailed: each student's feedback file is embedded in it, so nothing else needs to travel with it. Its title
names the lab and the gradebook's date. It shows the distribution of total scores, each checkpoint's
outcomes (the gradebook's ``status`` column) as a stacked bar (pass rate = passed / submissions), the most
frequent failure messages per checkpoint with their numbers masked (:func:`mistake`) so that the same
classic mistake groups together, the students who attempted nothing, timed out, hit a limit, were refused
or not graded, and one row per student linking their feedback.

Everything from the gradebook (names, messages, feedback: students control all of it) is shown as text:
control characters, bidirectional overrides included, as ``[U+XXXX]`` (:mod:`.quoting`), then HTML-escaped;
long tokens wrap (``overflow-wrap: anywhere``) and each string is clipped. So the page's size is bounded:
at most :func:`page_bound` bytes for N submissions and M checkpoints, O(N·M).
"""

from __future__ import annotations

import html
import math
import re
import statistics
import sys
import time
from collections import Counter
from pathlib import Path

from ..checkpoints import Status
from .gradebook import SubmissionGrade, default_feedback_dir, feedback_names, read_gradebook
from .quoting import clip, visible_controls

#: outcome → colour (Okabe–Ito, colour-blind safe; error in Tol's wine, readable as text; greys), in the order
#: the bars stack
OUTCOMES = {
    Status.PASSED: "#009E73",
    Status.FAILED: "#D55E00",
    Status.ERROR: "#882255",
    Status.MISSING: "#CC79A7",
    Status.NOT_ATTEMPTED: "#999999",
    Status.TIMED_OUT: "#E69F00",
    Status.OVER_LIMIT: "#56B4E9",
    Status.NOT_GRADED: "#0072B2",
    Status.REFUSED: "#000000",
    Status.UNKNOWN: "#DDDDDD",
}
MISTAKES = (Status.FAILED, Status.ERROR, Status.UNKNOWN)  # rows whose messages are grouped into mistakes
TOP_MISTAKES = 3  # failure groups shown per checkpoint
MAX_BARS = 40  # bars of the score histogram at most (a bar spans several points when the total is large)
NAME_CHARS, CHECKPOINT_CHARS, MESSAGE_CHARS = 120, 60, 300  # characters shown of each
FEEDBACK_CHARS = 16_000  # characters of each student's feedback file embedded


def page_bound(n: int, m: int) -> int:
    """Bytes the page may take for ``n`` submissions and ``m`` checkpoints: each shown character becomes at
    most 8 bytes ("[U+202E]", or "&quot;" and a 4-byte UTF-8 character are fewer), plus the markup."""
    shown = 8
    per_checkpoint = 4_000 + TOP_MISTAKES * (CHECKPOINT_CHARS + 2 * MESSAGE_CHARS) * shown
    per_student = 2_000 + (2 * NAME_CHARS + FEEDBACK_CHARS) * shown
    per_cell = 200 + MESSAGE_CHARS * shown
    return 16_000 + MAX_BARS * 400 + m * per_checkpoint + n * per_student + n * m * per_cell


_NUMBER_CHARS = re.compile(r"[\w.]+")  # one character class: each match is one forward pass
_KEPT = re.compile(r"\bvalue \d+ of \d+\b|\b\d+ values?\b")  # which output, how many: part of the mistake


def mistake(message: str) -> str:
    """A failure message reduced to the mistake it names, so that the class's messages group.

    Drops the hint (the same for every student), the count of cases passed and the failing input
    (random per submission), and masks every number as ``#`` except "value k of n" and "n values"
    (which output is wrong, how many were returned) and the whole numbers of the judge's explanation
    after " — " ("exactly 180° off"); a list of numbers becomes ``(…)``. Linear in the message's length.
    """
    text = re.split(r"\.? Hint: ", message, maxsplit=1)[0]
    raised = re.search(r"\) raised (\w+: .*)$", text, re.S)
    if raised:
        text = "raised " + raised.group(1)
    else:
        first = re.match(r"^\d+/\d+ [^;]*; first failure ", text)
        if first:
            text = _after_case(text[first.end() :])
    problem, dash, why = text.partition(" — ")
    parts, last = [], 0
    for kept in _KEPT.finditer(problem):
        parts += [mask_numbers(problem[last : kept.start()]), kept.group()]
        last = kept.end()
    text = "".join(parts) + mask_numbers(problem[last:]) + dash + mask_numbers(why, keep_whole=True)
    text = re.sub(r"\(#(, #)*\)", "(…)", text)
    return re.sub(r"\s+", " ", text).strip()


def mask_numbers(text: str, keep_whole: bool = False) -> str:
    """``text`` with each number (``12``, ``-0.5``, ``2.6e-06``, ``.5``; not part of a word like ``x2``) as
    ``#``, whole numbers kept when ``keep_whole``. One pass over the text (no backtracking search)."""
    out, i = [], 0
    while i < len(text):
        run = _NUMBER_CHARS.match(text, i)
        if run is None:  # a character that is neither a word character nor a dot
            out.append(text[i])
            i += 1
            continue
        token, end = run.group(), run.end()
        if token[-1] in "eE" and text[end : end + 1] in ("+", "-") and text[end + 1 : end + 2].isdecimal():
            exponent = _NUMBER_CHARS.match(text, end + 1)  # 2.6e-06: the exponent's sign splits the run
            if _is_number(token + text[end] + exponent.group()):
                token, end = token + text[end] + exponent.group(), exponent.end()
        if not _is_number(token) or keep_whole and token.isdecimal():
            out.append(token)
        elif text[i - 1 : i] in ("-", "−") and (i < 2 or not _NUMBER_CHARS.match(text[i - 2])):
            out[-1] = "#"  # its sign (the character before: not a word or a number's, so x-1 keeps its minus)
        else:
            out.append("#")
        i = end
    return "".join(out)


def _is_number(token: str) -> bool:
    """``token`` (a run of word characters and dots) is ``\\d+(.\\d*)?`` or ``.\\d+``, then maybe ``[eE][-+]?\\d+``."""
    mantissa, e, exponent = token.replace("E", "e").partition("e")
    if e and not (exponent[1:] if exponent[:1] in ("+", "-") else exponent).isdecimal():
        return False
    whole, _, fraction = mantissa.partition(".")
    if whole and not whole.isdecimal() or fraction and not fraction.isdecimal():
        return False
    return bool(whole or fraction)


def _after_case(text: str) -> str:
    """``text`` after its leading case (``f(a=1, b=(2, 3))`` or a label) and the ``: `` that ends it."""
    if re.match(r"\w+\(", text):
        depth = 0
        for i, ch in enumerate(text):
            depth += (ch == "(") - (ch == ")")
            if depth == 0 and ch == ")":
                return text[i + 1 :].removeprefix(": ")
    head, sep, rest = text.partition(": ")
    return rest if sep else head


def write_report(gradebook: Path, out: Path | None = None, feedback_dir: Path | None = None) -> Path:
    """Read ``gradebook`` (ValueError naming file and line if it is not one), write the HTML page; → its path."""
    gradebook = Path(gradebook)
    out = Path(out or gradebook.with_name(gradebook.stem + "_report.html"))
    feedback_dir = Path(feedback_dir or default_feedback_dir(gradebook))
    grades = read_gradebook(gradebook)
    if not grades:
        raise ValueError(f"{gradebook}: the gradebook holds no submission (only its header)")
    feedback = {}
    for g, name in zip(grades, feedback_names([g.submission for g in grades])):
        try:
            with open(feedback_dir / name, encoding="utf-8", errors="replace") as f:
                feedback[g.submission] = f.read(FEEDBACK_CHARS + 1)
        except OSError:  # none (or a hand-edited name no file can have)
            pass
    labs = sorted({r.checkpoint.partition(".")[0] for g in grades for r in g.rows if "." in r.checkpoint})
    lab = ("Lab " + labs[0]) if len(labs) == 1 else ("Labs " + ", ".join(labs)) if labs else "Class"
    date = time.strftime("%Y-%m-%d", time.localtime(gradebook.stat().st_mtime))
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        render(grades, title=f"{lab} class report, {date} ({gradebook.name})", feedback=feedback), encoding="utf-8"
    )
    return out


def checkpoint_names(grades: list[SubmissionGrade]) -> list[str]:
    """Checkpoint names in the order they first appear in the gradebook."""
    return list(dict.fromkeys(r.checkpoint for g in grades for r in g.rows))


def _text(value: str, limit: int) -> str:
    """Student text for the page: clipped, control characters shown, HTML-escaped (quotes too)."""
    return html.escape(visible_controls(clip(value, limit)))


def render(grades: list[SubmissionGrade], title: str, feedback: dict[str, str]) -> str:
    """The whole page; ``feedback`` maps a submission to the text of its feedback file (embedded)."""
    names = checkpoint_names(grades)
    totals = [g.points for g in grades]
    top = max(g.max_points for g in grades)
    outcomes = {n: Counter(r.status for g in grades for r in g.rows if r.checkpoint == n) for n in names}
    parts = [
        f"<h1>{_text(title, 200)}</h1>",
        f"<p>{len(grades)} submissions, {len(names)} checkpoints; total score mean "
        f"{sum(totals) / len(totals):.2f} / {top:g}, median {statistics.median(totals):g}.</p>",
        "<h2>Score distribution</h2>",
        _histogram(totals, top),
        "<h2>Outcomes per checkpoint</h2>",
        _legend(outcomes),
        _stacked_bars(names, outcomes, len(grades)),
        "<h2>Most frequent failures</h2>",
        _mistakes(grades, names),
        "<h2>Students to follow up</h2>",
        _follow_up(grades),
        "<h2>Every student</h2>",
        _students(grades, names, feedback),
        "<h2>Each student's feedback</h2>",
        _feedback(grades, feedback),
    ]
    csp = "default-src 'none'; style-src 'unsafe-inline'; img-src data:"
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="Content-Security-Policy" content="{csp}">'
        f"<title>{_text(title, 200)}</title><style>{_CSS}</style></head>\n<body>\n"
        + "\n".join(parts)
        + "\n</body></html>\n"
    )


_CSS = (
    "body{font-family:sans-serif;max-width:70em;margin:1em auto;color:#222}"
    ".wrap,pre,h3{overflow-wrap:anywhere}"  # a long token (a name, a message) wraps instead of stretching the page
    "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;text-align:left;vertical-align:top}"
    "td.num{text-align:right}.legend span{display:inline-block;margin-right:1em}"
    ".sw{display:inline-block;width:.9em;height:.9em;margin-right:.3em;vertical-align:middle;border:1px solid #888}"
    "pre{white-space:pre-wrap;background:#f6f6f6;padding:.5em}svg text{font-family:sans-serif;font-size:12px}"
)


def _histogram(totals, top) -> str:
    """Bars of how many students scored in [k·w, (k+1)·w) points, w whole points so that there are at most
    MAX_BARS bars (w = 1 for kfkit's labs); the top score counts in the last bar."""
    width_pts = max(1, math.ceil((math.ceil(top) + 1) / MAX_BARS))
    bins = list(range(0, int(math.ceil(top)) + 1, width_pts))
    counts = Counter(min(int(t // width_pts) * width_pts, bins[-1]) for t in totals)
    width, height, left, bottom = 40 * len(bins) + 60, 220, 40, 40
    scale = (height - bottom - 20) / max(counts.values())
    out = [
        f'<svg class="chart histogram" role="img" aria-label="score distribution" width="{width}" '
        f'height="{height}" xmlns="http://www.w3.org/2000/svg">'
    ]
    for i, k in enumerate(bins):
        h, x = counts.get(k, 0) * scale, left + 40 * i
        out.append(
            f'<rect class="bar" data-points="{k}" data-count="{counts.get(k, 0)}" x="{x + 4}" '
            f'y="{height - bottom - h:.1f}" width="32" height="{h:.1f}" fill="#0072B2"/>'
        )
        out.append(f'<text x="{x + 20}" y="{height - bottom + 15}" text-anchor="middle">{k}</text>')
        if counts.get(k):
            out.append(f'<text x="{x + 20}" y="{height - bottom - h - 4:.1f}" text-anchor="middle">{counts[k]}</text>')
    out.append(f'<line x1="{left}" y1="{height - bottom}" x2="{width - 20}" y2="{height - bottom}" stroke="#222"/>')
    each = (
        f"bar = number of students with {width_pts} points from its label"
        if width_pts > 1
        else "bar = number of students"
    )
    out.append(
        f'<text x="{left + (width - left) / 2}" y="{height - 5}" text-anchor="middle">total points '
        f"(of {top:g}); {each}</text></svg>"
    )
    return "\n".join(out)


def _legend(outcomes) -> str:
    seen = {s for counts in outcomes.values() for s in counts}
    return (
        '<p class="legend">'
        + "".join(
            f'<span><i class="sw" style="background:{c}"></i>{k}</span>' for k, c in OUTCOMES.items() if k in seen
        )
        + "</p>"
    )


def _stacked_bars(names, outcomes, n) -> str:
    """One horizontal bar per checkpoint, its segments the share of each outcome; pass rate printed."""
    label_w, bar_w, row_h = 180, 500, 26
    height = row_h * len(names) + 10
    out = [
        f'<svg class="chart pass-rates" role="img" aria-label="outcomes per checkpoint" width="{label_w + bar_w + 70}" '
        f'height="{height}" xmlns="http://www.w3.org/2000/svg">'
    ]
    for i, name in enumerate(names):
        y, x, shown = 5 + row_h * i, label_w, _text(name, CHECKPOINT_CHARS)
        out.append(f'<text x="{label_w - 6}" y="{y + 15}" text-anchor="end">{shown}</text>')
        for kind, colour in OUTCOMES.items():
            count = outcomes[name].get(kind, 0)
            if count:
                w = bar_w * count / n
                out.append(
                    f'<rect class="segment" data-checkpoint="{shown}" data-outcome="{kind}" '
                    f'data-count="{count}" x="{x:.1f}" y="{y}" width="{w:.1f}" height="{row_h - 6}" '
                    f'fill="{colour}"><title>{shown}: {count} {kind}</title></rect>'
                )
                x += w
        rate = 100 * outcomes[name].get(Status.PASSED, 0) / n
        out.append(f'<text class="rate" x="{label_w + bar_w + 6}" y="{y + 15}">{rate:.0f} %</text>')
    out.append("</svg>")
    return "\n".join(out)


def _mistakes(grades, names) -> str:
    rows = []
    for name in names:
        failing = [
            (mistake(r.message), r.message)
            for g in grades
            for r in g.rows
            if r.checkpoint == name and r.status in MISTAKES
        ]
        groups = Counter(text for text, _ in failing)
        for text, count in groups.most_common(TOP_MISTAKES):
            example = next(message for key, message in failing if key == text)
            rows.append(
                f'<tr class="mistake"><td>{_text(name, CHECKPOINT_CHARS)}</td><td class="num">{count}</td>'
                f'<td class="wrap">{_text(text, MESSAGE_CHARS)}<br><small>e.g. {_text(example, MESSAGE_CHARS)}'
                "</small></td></tr>"
            )
    if not rows:
        return "<p>No checkpoint failed.</p>"
    return (
        "<table><tr><th>checkpoint</th><th>students</th><th>mistake (numbers masked as #)</th></tr>\n"
        + "\n".join(rows)
        + "</table>"
    )


def _follow_up(grades) -> str:
    def any_of(g, *statuses):
        return any(r.status in statuses for r in g.rows)

    groups = {
        "attempted nothing": [
            g for g in grades if all(r.status in (Status.NOT_ATTEMPTED, Status.MISSING) for r in g.rows)
        ],
        "timed out or stopped by a limit": [g for g in grades if any_of(g, Status.TIMED_OUT, Status.OVER_LIMIT)],
        "not graded (regrade them)": [g for g in grades if any_of(g, Status.NOT_GRADED)],
        "refused (a link or not a regular file: ask for the notebook itself)": [
            g for g in grades if any_of(g, Status.REFUSED)
        ],
    }
    return (
        "<ul>"
        + "".join(
            f'<li class="follow-up wrap" data-group="{k.split(" (")[0]}">{k} ({len(v)}): '
            + (", ".join(_text(g.submission, NAME_CHARS) for g in v) or "none")
            + "</li>"
            for k, v in groups.items()
        )
        + "</ul>"
    )


def _students(grades, names, feedback) -> str:
    symbol = {Status.PASSED: "✓", Status.NOT_ATTEMPTED: "–"}
    head = "".join(f"<th>{_text(n, CHECKPOINT_CHARS)}</th>" for n in names)
    rows = []
    for k, g in enumerate(grades):
        by_name = {r.checkpoint: r for r in g.rows}
        who = _text(g.submission, NAME_CHARS)
        who = (
            f'<a href="#feedback-{k}">{who}</a>'
            if g.submission in feedback
            else f"{who} <small>(no feedback file)</small>"
        )
        cells = []
        for n in names:
            r = by_name.get(n)
            if r is None:
                cells.append("<td></td>")
                continue
            cells.append(
                f'<td title="{_text(r.message, MESSAGE_CHARS)}" style="color:{OUTCOMES[r.status]}">'
                f"{symbol.get(r.status, '✗')} {r.points:g}</td>"
            )
        rows.append(
            f'<tr class="student"><td class="wrap">{who}</td><td class="num">{g.points:g} / {g.max_points:g}</td>'
            + "".join(cells)
            + "</tr>"
        )
    return f"<table><tr><th>submission</th><th>score</th>{head}</tr>\n" + "\n".join(rows) + "</table>"


def _feedback(grades, feedback) -> str:
    """Each feedback file as text (its Markdown not rendered), so the page needs no folder beside it."""
    parts = [
        f'<section class="feedback" id="feedback-{k}"><h3>{_text(g.submission, NAME_CHARS)}</h3>'
        f"<pre>{html.escape(clip(visible_controls(feedback[g.submission], lines=True), FEEDBACK_CHARS))}</pre>"
        "</section>"
        for k, g in enumerate(grades)
        if g.submission in feedback
    ]
    return "\n".join(parts) or "<p>No feedback file was found beside the gradebook.</p>"


def cli(args) -> int:
    """``kfkit report``: write the page; exit 2 with the reason when the gradebook cannot be read."""
    try:
        out = write_report(args.gradebook, args.out, args.feedback)
    except (OSError, ValueError) as exc:
        print(f"kfkit report: {exc}", file=sys.stderr)
        return 2
    print(f"class report: {out}")
    return 0
