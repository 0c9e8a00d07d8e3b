"""A corpus of valid ways of writing a lab's exercises, for the exercise guard's differential test: each way rewrites
every exercise function of the solution notebook (the functions make-labs turns into stubs) with one construct
(decorators, closures, classes, comprehensions, walrus, match, try, generators, magics, star imports, globals, …),
keeping what it computes. :func:`variants` returns, per way, the exercise cells as a student might have written them.
"""

from __future__ import annotations

import ast
import copy
import textwrap
from dataclasses import dataclass

import nbformat

from kfkit.authoring import BEGIN


def python(source: str) -> str:
    """A cell's Python: IPython's % and ! lines blanked (line numbers kept)."""
    return "\n".join("" if line.lstrip().startswith(("%", "!")) else line for line in source.split("\n"))


def exercise_cells(solution: nbformat.NotebookNode) -> list[tuple[str, list[str]]]:
    """(source, exercise functions it defines) of each code cell of a solution notebook that holds an exercise: a
    function with a solution block in its own body (the innermost function around each BEGIN marker)."""
    found = []
    for cell in solution.cells:
        if cell.cell_type != "code" or BEGIN not in cell.source:
            continue
        defs = [n for n in ast.walk(ast.parse(python(cell.source))) if isinstance(n, ast.FunctionDef)]
        names = []
        for number, line in enumerate(cell.source.split("\n"), start=1):
            if BEGIN in line:
                around = [d for d in defs if d.lineno < number <= d.end_lineno]
                if around:
                    names.append(max(around, key=lambda d: d.lineno).name)
        found.append((cell.source, list(dict.fromkeys(names))))
    return found


@dataclass
class Way:
    name: str
    cells: list[str]  # the exercise cells, in the notebook's order


# --- helpers on a function's AST --------------------------------------------------------------------------------


def _docstring(fn: ast.FunctionDef) -> tuple[list[ast.stmt], list[ast.stmt]]:
    body = fn.body
    if (
        body
        and isinstance(body[0], ast.Expr)
        and isinstance(getattr(body[0], "value", None), ast.Constant)
        and isinstance(body[0].value.value, str)
    ):
        return body[:1], body[1:]
    return [], body


def _forward(fn: ast.FunctionDef, callee: str) -> str:
    """``callee(…)`` passing on every parameter of ``fn`` as it came."""
    a = fn.args
    parts = [p.arg for p in a.posonlyargs + a.args]
    parts += [f"*{a.vararg.arg}"] if a.vararg else []
    parts += [f"{p.arg}={p.arg}" for p in a.kwonlyargs]
    parts += [f"**{a.kwarg.arg}"] if a.kwarg else []
    return f"{callee}({', '.join(parts)})"


def _stmts(source: str) -> list[ast.stmt]:
    return ast.parse(textwrap.dedent(source)).body


def _renamed(fn: ast.FunctionDef, name: str) -> ast.FunctionDef:
    new = copy.deepcopy(fn)
    new.name = name
    return new


def _with_body(fn: ast.FunctionDef, body: list[ast.stmt], keep_doc=True) -> ast.FunctionDef:
    new = copy.deepcopy(fn)
    new.body = (_docstring(fn)[0] if keep_doc else []) + body
    return new


def _src(*nodes: ast.AST) -> str:
    return "\n".join(ast.unparse(ast.fix_missing_locations(n)) for n in nodes)


def _inner(fn: ast.FunctionDef) -> ast.FunctionDef:
    """The body of ``fn`` as an inner function ``compute`` taking the same parameters."""
    _, rest = _docstring(fn)
    return _with_body(_renamed(fn, "compute"), copy.deepcopy(rest), keep_doc=False)


def _first_param(fn: ast.FunctionDef) -> str:
    return (fn.args.posonlyargs + fn.args.args + fn.args.kwonlyargs)[0].arg


def _body_wrapped(fn: ast.FunctionDef, template: str) -> ast.FunctionDef:
    """``fn`` with its body (after the docstring) put where ``template`` says ``BODY`` (an indented line)."""
    _, rest = _docstring(fn)
    holder = _stmts(template)
    for node in ast.walk(ast.Module(body=holder, type_ignores=[])):
        for field in ("body", "orelse", "finalbody"):
            block = getattr(node, field, None)
            if isinstance(block, list):
                for i, stmt in enumerate(block):
                    if isinstance(stmt, ast.Expr) and isinstance(stmt.value, ast.Name) and stmt.value.id == "BODY":
                        block[i : i + 1] = copy.deepcopy(rest)
    return _with_body(fn, holder)


def _via_compute(fn: ast.FunctionDef, tail: str) -> ast.FunctionDef:
    """``fn`` computing through its inner ``compute``, ``tail`` using CALL (the forwarding call)."""
    return _with_body(fn, [_inner(fn)] + _stmts(tail.replace("CALL", _forward(fn, "compute"))))


# --- the ways: each maps one exercise function (AST) to the source that replaces it in its cell ---------------------


def _impl(fn):
    """The function under another name, for the ways that bind the exercise's name some other way."""
    return _src(_renamed(fn, f"impl_{fn.name}"))


WAYS = {
    "unparsed": lambda fn: _src(fn),
    "wraps_decorator": lambda fn: (
        f"import functools\n\ndef traced_{fn.name}(f):\n    @functools.wraps(f)\n    def wrapper(*args, **kwargs):\n"
        f"        return f(*args, **kwargs)\n    return wrapper\n\n@traced_{fn.name}\n{_src(fn)}"
    ),
    "plain_decorator": lambda fn: (
        f"def passed_{fn.name}(f):\n    def wrapper(*args, **kwargs):\n        return f(*args, **kwargs)\n"
        f"    return wrapper\n\n@passed_{fn.name}\n{_src(fn)}"
    ),
    "stacked_decorators": lambda fn: (
        f"import functools\n\ndef outer_{fn.name}(f):\n    return functools.wraps(f)(lambda *a, **k: f(*a, **k))\n\n"
        f"def inner_{fn.name}(f):\n    f.tagged = True\n    return f\n\n@outer_{fn.name}\n@inner_{fn.name}\n{_src(fn)}"
    ),
    "decorator_with_arguments": lambda fn: (
        f"def labelled_{fn.name}(label):\n    def decorate(f):\n        f.label = label\n        return f\n"
        f"    return decorate\n\n@labelled_{fn.name}('exercise')\n{_src(fn)}"
    ),
    "closure_factory": lambda fn: (
        f"def make_{fn.name}():\n{textwrap.indent(_src(fn), '    ')}\n    return {fn.name}\n\n"
        f"{fn.name} = make_{fn.name}()"
    ),
    "nonlocal_counter": lambda fn: (
        f"def counted_{fn.name}(f):\n    calls = 0\n    def wrapper(*args, **kwargs):\n        nonlocal calls\n"
        f"        calls += 1\n        return f(*args, **kwargs)\n    return wrapper\n\n{_impl(fn)}\n\n"
        f"{fn.name} = counted_{fn.name}(impl_{fn.name})"
    ),
    "staticmethod": lambda fn: (
        f"class Exercise_{fn.name}:\n    @staticmethod\n{textwrap.indent(_src(fn), '    ')}\n\n"
        f"{fn.name} = Exercise_{fn.name}.{fn.name}"
    ),
    "bound_method": lambda fn: (
        f"class Solver_{fn.name}:\n    def solve(self, *args, **kwargs):\n"
        f"        return impl_{fn.name}(*args, **kwargs)\n\n"
        f"{_impl(fn)}\n\n{fn.name} = Solver_{fn.name}().solve"
    ),
    "classmethod": lambda fn: (
        f"class Tools_{fn.name}:\n    @classmethod\n    def run(cls, *args, **kwargs):\n"
        f"        return impl_{fn.name}(*args, **kwargs)\n\n"
        f"{_impl(fn)}\n\n{fn.name} = Tools_{fn.name}.run"
    ),
    "callable_instance": lambda fn: (
        f"{_impl(fn)}\n\nclass Callable_{fn.name}:\n    def __call__(self, *args, **kwargs):\n"
        f"        return impl_{fn.name}(*args, **kwargs)\n\n{fn.name} = Callable_{fn.name}()"
    ),
    "dataclass_holder": lambda fn: (
        f"import dataclasses\n\n{_impl(fn)}\n\n@dataclasses.dataclass\n"
        f"class Holder_{fn.name}:\n    function: object\n\n"
        f"{fn.name} = Holder_{fn.name}(impl_{fn.name}).function"
    ),
    "lambda_alias": lambda fn: f"{_impl(fn)}\n\n{fn.name} = lambda *args, **kwargs: impl_{fn.name}(*args, **kwargs)",
    "partial": lambda fn: f"import functools\n\n{_impl(fn)}\n\n{fn.name} = functools.partial(impl_{fn.name})",
    "exec": lambda fn: f"exec({_src(fn)!r})",
    "globals_assignment": lambda fn: f"{_impl(fn)}\n\nglobals()[{fn.name!r}] = impl_{fn.name}",
    "globals_update": lambda fn: f"{_impl(fn)}\n\nglobals().update({{{fn.name!r}: impl_{fn.name}}})",
    "getattr_module": lambda fn: (
        f"import sys\n\n{_impl(fn)}\n\n{fn.name} = getattr(sys.modules[__name__], 'impl_{fn.name}')"
    ),
    "global_counter": lambda fn: _src(
        _with_body(
            fn,
            _stmts(f"global calls_{fn.name}\ncalls_{fn.name} = globals().get('calls_{fn.name}', 0) + 1")
            + _docstring(fn)[1],
        )
    ),
    "raises_it_for_an_input_it_does_not_take": lambda fn: _src(
        _with_body(
            fn,
            _stmts(f"if {_first_param(fn)} is NotImplemented:\n    raise NotImplementedError('not for NotImplemented')")
            + _docstring(fn)[1],
        )
    ),
    "stub_left_after_return": lambda fn: _src(_via_compute(fn, "return CALL\nraise NotImplementedError()")),
    "stub_in_an_else": lambda fn: _src(_body_wrapped(fn, "if True:\n    BODY\nelse:\n    raise NotImplementedError()")),
    "catches_not_implemented": lambda fn: _src(
        _body_wrapped(fn, "try:\n    BODY\nexcept NotImplementedError:\n    raise NotImplementedError()")
    ),
    "try_finally": lambda fn: _src(_body_wrapped(fn, "try:\n    BODY\nfinally:\n    cleaned = True")),
    "with_block": lambda fn: (
        "import contextlib\n\n" + _src(_body_wrapped(fn, "with contextlib.nullcontext():\n    BODY"))
    ),
    "match": lambda fn: _src(_body_wrapped(fn, f"match {_first_param(fn)}:\n    case _:\n        BODY")),
    "for_loop": lambda fn: _src(_body_wrapped(fn, "for attempt in range(1):\n    BODY")),
    "while_loop": lambda fn: _src(_body_wrapped(fn, "while True:\n    BODY\n    break")),
    "walrus": lambda fn: _src(_via_compute(fn, "if (result := CALL) is not None:\n    return result\nreturn result")),
    "list_comprehension": lambda fn: _src(_via_compute(fn, "return [CALL for attempt in range(1)][0]")),
    "generator_expression": lambda fn: _src(_via_compute(fn, "return next(CALL for attempt in (None,))")),
    "generator_function": lambda fn: _src(_via_compute(fn, "def results():\n    yield CALL\nreturn next(results())")),
    "inner_names_like_the_labs_variables": lambda fn: _src(
        _with_body(
            fn,
            _stmts("probe = lambda r, roll_acc, x0: r\ndef probe_unused(t, dt, rec):\n    return [t for t in (t, dt)]")
            + _docstring(fn)[1],
        )
    ),
    "annotations": lambda fn: _src(_annotated(fn)),
}

#: ways that change the whole cell: (a prefix line, applied to the unchanged cell)
CELL_WAYS = {
    "as_written": "",
    "star_import": "from math import *\n",
    "line_magic": "%reset_selective -f ^no_such_name_at_all$\n",
    "cell_magic": "%%capture captured\n",
}


def _annotated(fn: ast.FunctionDef) -> ast.FunctionDef:
    new = copy.deepcopy(fn)
    for a in new.args.posonlyargs + new.args.args + new.args.kwonlyargs:
        a.annotation = ast.Constant("object")
    new.returns = ast.Constant("object")
    return new


def variants(solution: nbformat.NotebookNode) -> list[Way]:
    """Every way of writing the lab's exercises: one per construct, each applied to every exercise function."""
    cells = exercise_cells(solution)
    ways = [Way(name, [prefix + source for source, _ in cells]) for name, prefix in CELL_WAYS.items()]
    for name, rewrite in WAYS.items():
        rewritten = []
        for source, exercises in cells:
            tree = ast.parse(python(source))
            parts = [
                rewrite(node) if isinstance(node, ast.FunctionDef) and node.name in exercises else _src(node)
                for node in tree.body
            ]
            rewritten.append("\n\n".join(parts) + "\n")
        ways.append(Way(name, rewritten))
    return ways
