"""The class report: a gradebook → one self-contained HTML page the instructor looks at.

    kfkit report gradebook.csv            # → gradebook_report.html beside it

The page holds everything inline (SVG charts, a ``<style>`` block, no script, no font, no link to
another site; its Content-Security-Policy forbids loading anything), so it opens offline and can be
mailed. It shows the distribution of total scores, each checkpoint's outcomes as a stacked bar
(pass rate = passed / submissions), the most frequent failure messages per checkpoint with their
numbers masked (:func:`mistake`) so that the same classic mistake groups together, the students who
attempted nothing, timed out, hit a limit or were not graded, and one row per student linking the
feedback file ``kfkit grade`` wrote (``<gradebook stem>_feedback/<submission>.md``).

Every string from the gradebook (names, messages: students control both) is HTML-escaped.
"""
from __future__ import annotations

import html
import math
import os
import re
import statistics
import sys
import urllib.parse
from collections import Counter
from pathlib import Path

from .core import Row, SubmissionGrade, default_feedback_dir, feedback_names, read_gradebook

#: outcome → colour (Okabe–Ito, colour-blind safe), in the order the bars stack
OUTCOMES = {"passed": "#009E73", "failed": "#D55E00", "missing": "#CC79A7", "not attempted": "#999999",
            "timed out": "#E69F00", "over limit": "#56B4E9", "not graded": "#0072B2"}
TOP_MISTAKES = 3  # failure groups shown per checkpoint

# The gradebook keeps points and message, not the status: these read it back from the messages core.py writes.
_STATUS_PATTERNS = [
    ("not attempted", re.compile(r"^not attempted \(")),
    ("timed out", re.compile(r"^(timed out: |\w+ timed out after |calling \w+ on the grader's cases: timed out after )")),
    ("over limit", re.compile(r"^not graded, stopped: ")),
    ("not graded", re.compile(r"^(not graded: |GRADER ERROR)")),
    ("missing", re.compile(r"^no function named |^\w+ is a \w+ at the end of the notebook, not a function$")),
]
_NUMBER = re.compile(r"(?<![\w.])[-−]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(?![\w.])")
_KEPT = re.compile(r"\bvalue \d+ of \d+\b|\b\d+ values?\b")  # which output, how many: part of the mistake


def outcome(row: Row) -> str:
    """The row's outcome (a key of :data:`OUTCOMES`): passed when it has all its points (> 0), else
    what its message says (not attempted, timed out, …), else failed."""
    if row.points == row.max_points > 0:
        return "passed"
    return next((name for name, pattern in _STATUS_PATTERNS if pattern.search(row.message)), "failed")


def mistake(message: str) -> str:
    """A failure message reduced to the mistake it names, so that the class's messages group.

    Drops the hint (the same for every student), the count of cases passed and the failing input
    (random per submission), and masks every number as ``#`` except "value k of n" and "n values"
    (which output is wrong, how many were returned); a list of numbers becomes ``(…)``.
    """
    text = re.split(r"\.? Hint: ", message, maxsplit=1)[0]
    raised = re.search(r"\) raised (\w+: .*)$", text, re.S)
    if raised:
        text = "raised " + raised.group(1)
    else:
        first = re.match(r"^\d+/\d+ [^;]*; first failure ", text)
        if first:
            text = _after_case(text[first.end():])
    kept = _KEPT.findall(text)
    text = _NUMBER.sub("#", _KEPT.sub("\0", text))
    text = re.sub(r"\(#(, #)*\)", "(…)", text)
    for k in kept:
        text = text.replace("\0", k, 1)
    return re.sub(r"\s+", " ", text).strip()


def _after_case(text: str) -> str:
    """``text`` after its leading case (``f(a=1, b=(2, 3))`` or a label) and the ``: `` that ends it."""
    if re.match(r"\w+\(", text):
        depth = 0
        for i, ch in enumerate(text):
            depth += (ch == "(") - (ch == ")")
            if depth == 0 and ch == ")":
                return text[i + 1:].removeprefix(": ")
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
    links = {}
    for g, name in zip(grades, feedback_names([g.submission for g in grades])):
        if (feedback_dir / name).is_file():
            links[g.submission] = urllib.parse.quote(Path(os.path.relpath(feedback_dir / name, out.parent)).as_posix())
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(render(grades, title=f"Class report: {gradebook.name}", links=links), encoding="utf-8")
    return out


def checkpoint_names(grades: list[SubmissionGrade]) -> list[str]:
    """Checkpoint names in the order they first appear in the gradebook."""
    return list(dict.fromkeys(r.checkpoint for g in grades for r in g.rows))


def render(grades: list[SubmissionGrade], title: str, links: dict[str, str]) -> str:
    """The whole page; ``links`` maps a submission to the (already URL-quoted) relative link of its feedback."""
    e = html.escape
    names = checkpoint_names(grades)
    totals = [g.points for g in grades]
    top = max(g.max_points for g in grades)
    outcomes = {n: Counter(outcome(r) for g in grades for r in g.rows if r.checkpoint == n) for n in names}
    parts = [f"<h1>{e(title)}</h1>",
             f"<p>{len(grades)} submissions, {len(names)} checkpoints; total score mean "
             f"{sum(totals) / len(totals):.2f} / {top:g}, median {statistics.median(totals):g}.</p>",
             "<h2>Score distribution</h2>", _histogram(totals, top),
             "<h2>Outcomes per checkpoint</h2>", _legend(), _stacked_bars(names, outcomes, len(grades)),
             "<h2>Most frequent failures</h2>", _mistakes(grades, names),
             "<h2>Students to follow up</h2>", _follow_up(grades),
             "<h2>Every student</h2>", _students(grades, names, links)]
    csp = "default-src 'none'; style-src 'unsafe-inline'; img-src data:"
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<meta http-equiv=\"Content-Security-Policy\" content=\"{csp}\">"
            f"<title>{e(title)}</title><style>{_CSS}</style></head>\n<body>\n" + "\n".join(parts) + "\n</body></html>\n")


_CSS = ("body{font-family:sans-serif;max-width:70em;margin:1em auto;color:#222}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:2px 6px;text-align:left;vertical-align:top}"
        "td.num{text-align:right}.legend span{display:inline-block;margin-right:1em}"
        ".sw{display:inline-block;width:.9em;height:.9em;margin-right:.3em;vertical-align:middle}"
        "svg text{font-family:sans-serif;font-size:12px}")


def _histogram(totals, top) -> str:
    """Bars of how many students scored in [k, k+1) points, k = 0 … top (top in its own bar)."""
    bins = list(range(int(math.ceil(top)) + 1))
    counts = Counter(min(int(math.floor(t)), bins[-1]) for t in totals)
    width, height, left, bottom = 40 * len(bins) + 60, 220, 40, 40
    peak = max(counts.values())
    scale = (height - bottom - 20) / peak
    out = [f'<svg class="chart histogram" role="img" aria-label="score distribution" width="{width}" '
           f'height="{height}" xmlns="http://www.w3.org/2000/svg">']
    for i, k in enumerate(bins):
        h, x = counts.get(k, 0) * scale, left + 40 * i
        out.append(f'<rect class="bar" data-points="{k}" data-count="{counts.get(k, 0)}" x="{x + 4}" '
                   f'y="{height - bottom - h:.1f}" width="32" height="{h:.1f}" fill="#0072B2"/>')
        out.append(f'<text x="{x + 20}" y="{height - bottom + 15}" text-anchor="middle">{k}</text>')
        if counts.get(k):
            out.append(f'<text x="{x + 20}" y="{height - bottom - h - 4:.1f}" text-anchor="middle">{counts[k]}</text>')
    out.append(f'<line x1="{left}" y1="{height - bottom}" x2="{width - 20}" y2="{height - bottom}" stroke="#222"/>')
    out.append(f'<text x="{left + (width - left) / 2}" y="{height - 5}" text-anchor="middle">total points '
               f'(of {top:g}); bar = number of students</text></svg>')
    return "\n".join(out)


def _legend() -> str:
    return '<p class="legend">' + "".join(
        f'<span><i class="sw" style="background:{c}"></i>{html.escape(k)}</span>' for k, c in OUTCOMES.items()) + "</p>"


def _stacked_bars(names, outcomes, n) -> str:
    """One horizontal bar per checkpoint, its segments the share of each outcome; pass rate printed."""
    label_w, bar_w, row_h = 180, 500, 26
    height = row_h * len(names) + 10
    out = [f'<svg class="chart pass-rates" role="img" aria-label="outcomes per checkpoint" width="{label_w + bar_w + 70}" '
           f'height="{height}" xmlns="http://www.w3.org/2000/svg">']
    for i, name in enumerate(names):
        y, x = 5 + row_h * i, label_w
        out.append(f'<text x="{label_w - 6}" y="{y + 15}" text-anchor="end">{html.escape(name)}</text>')
        for kind, colour in OUTCOMES.items():
            count = outcomes[name].get(kind, 0)
            if count:
                w = bar_w * count / n
                out.append(f'<rect class="segment" data-checkpoint="{html.escape(name)}" data-outcome="{kind}" '
                           f'data-count="{count}" x="{x:.1f}" y="{y}" width="{w:.1f}" height="{row_h - 6}" '
                           f'fill="{colour}"><title>{html.escape(name)}: {count} {kind}</title></rect>')
                x += w
        rate = 100 * outcomes[name].get("passed", 0) / n
        out.append(f'<text class="rate" x="{label_w + bar_w + 6}" y="{y + 15}">{rate:.0f} %</text>')
    out.append("</svg>")
    return "\n".join(out)


def _mistakes(grades, names) -> str:
    rows = []
    for name in names:
        failing = [(mistake(r.message), r.message) for g in grades for r in g.rows
                   if r.checkpoint == name and outcome(r) == "failed"]
        groups = Counter(text for text, _ in failing)
        for text, count in groups.most_common(TOP_MISTAKES):
            example = next(message for key, message in failing if key == text)
            rows.append(f'<tr class="mistake"><td>{html.escape(name)}</td><td class="num">{count}</td>'
                        f'<td>{html.escape(text)}<br><small>e.g. {html.escape(example)}</small></td></tr>')
    if not rows:
        return "<p>No checkpoint failed.</p>"
    return ("<table><tr><th>checkpoint</th><th>students</th><th>mistake (numbers masked as #)</th></tr>\n"
            + "\n".join(rows) + "</table>")


def _follow_up(grades) -> str:
    groups = {
        "attempted nothing": [g for g in grades if all(outcome(r) in ("not attempted", "missing") for r in g.rows)],
        "timed out or stopped by a limit": [g for g in grades if any(outcome(r) in ("timed out", "over limit")
                                                                     for r in g.rows)],
        "not graded (regrade them)": [g for g in grades if any(outcome(r) == "not graded" for r in g.rows)],
    }
    return "<ul>" + "".join(
        f'<li class="follow-up" data-group="{k}">{k} ({len(v)}): '
        + (", ".join(html.escape(g.submission) for g in v) or "none") + "</li>" for k, v in groups.items()) + "</ul>"


def _students(grades, names, links) -> str:
    symbol = {"passed": "✓", "not attempted": "–"}
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    rows = []
    for g in grades:
        by_name = {r.checkpoint: r for r in g.rows}
        who = html.escape(g.submission)
        link = links.get(g.submission)
        who = f'<a href="{html.escape(link)}">{who}</a>' if link else f"{who} <small>(no feedback file)</small>"
        cells = []
        for n in names:
            r = by_name.get(n)
            if r is None:
                cells.append("<td></td>")
                continue
            kind = outcome(r)
            cells.append(f'<td title="{html.escape(r.message)}" style="color:{OUTCOMES[kind]}">'
                         f'{symbol.get(kind, "✗")} {r.points:g}</td>')
        rows.append(f'<tr class="student"><td>{who}</td><td class="num">{g.points:g} / {g.max_points:g}</td>'
                    + "".join(cells) + "</tr>")
    return f"<table><tr><th>submission</th><th>score</th>{head}</tr>\n" + "\n".join(rows) + "</table>"


def cli(args) -> int:
    """``kfkit report``: write the page; exit 2 with the reason when the gradebook cannot be read."""
    try:
        out = write_report(args.gradebook, args.out, args.feedback)
    except (OSError, ValueError) as exc:
        print(f"kfkit report: {exc}", file=sys.stderr)
        return 2
    print(f"class report: {out}")
    return 0
