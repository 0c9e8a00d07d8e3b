"""Run All goes to the end of a hand-out: cells that need an exercise not done yet say so and step aside.

A hand-out's exercises are stubs (``raise NotImplementedError()``, written by ``kfkit make-labs``). Without
this, Run All stops at the first cell that calls one, and a student who opened lab 00 to record data, or
wants to see lab 04's figures before writing the EKF, never reaches the rest. Loaded in a lab's first cell::

    %load_ext kfkit.exercise_guard

before each cell runs, IPython hands its code to :class:`ExerciseGuard`, which replaces the cell by a one-line
note when the cell

- is an unfinished exercise itself (a ``raise NotImplementedError`` outside any function): "fill in this cell";
- uses a function that is still a stub, or that calls one (followed through your own functions, into a
  function the same cell defines, and into a lambda handed on), or a name that only a skipped cell would
  have made: "needs kf_predict (not written yet)".

Everything else runs as usual, so the lab's own figures, the capture panel and every cell that needs no
exercise run. ``check("…", f)`` cells always run: the check itself says "not attempted yet". A solution
notebook, with nothing unfinished, runs exactly as without the guard.
"""
from __future__ import annotations

import ast
import builtins
import types

NOTE = "⏭  skipped: {why}. Run this cell again when that is done."


def _code_raises_not_implemented(code: types.CodeType) -> bool:
    """A stub: the function's code (or a nested one's) names NotImplementedError."""
    if "NotImplementedError" in code.co_names:
        return True
    return any(isinstance(c, types.CodeType) and _code_raises_not_implemented(c) for c in code.co_consts)


def _global_names(code: types.CodeType) -> set[str]:
    names = set(code.co_names)
    for c in code.co_consts:
        if isinstance(c, types.CodeType):
            names |= _global_names(c)
    return names


class ExerciseGuard:
    """The IPython input transformer (see the module doc); ``user_ns`` is the notebook's namespace."""

    is_exercise_guard = True  # how (un)loading finds it, also across %reload_ext (a new class object)

    def __init__(self, user_ns: dict):
        self.user_ns = user_ns
        self.missing: dict[str, tuple[str, str]] = {}  # name → (why a skipped cell did not make it, that cell's code)

    def unfinished(self, name: str, seen=None) -> str | None:
        """Why the notebook function ``name`` cannot run yet (its own stub, or a stub it calls), or None."""
        func = self.user_ns.get(name)
        if not isinstance(func, types.FunctionType) or func.__module__ not in ("__main__", None):
            return None
        if _code_raises_not_implemented(func.__code__):
            return f"{name} (not written yet)"
        seen = (seen or set()) | {name}
        for inner in sorted(_global_names(func.__code__) - seen):
            why = self.unfinished(inner, seen)
            if why:
                return f"{name}, which calls {why}"
        return None

    def __call__(self, lines: list[str]) -> list[str]:
        source = "".join(lines)
        try:
            tree = ast.parse(source)
        except SyntaxError:  # let IPython report it as usual
            return lines
        made = _assigned_names(tree)
        if _raises_at_top_level(tree):
            why, cause = ("this cell is an exercise: replace '# YOUR CODE HERE' and the raise below it with your code",
                          "an exercise cell not filled in yet")
        else:
            why, cause = self._needs(tree, source)
        if why is None:
            for name in made:
                self.missing.pop(name, None)
            return lines
        for name in made:
            self.missing[name] = (cause, source)  # the latest reason: the one before may be done by now
        return [f"print({NOTE.format(why=why)!r})\n"]

    def _needs(self, tree: ast.Module, source: str) -> tuple[str | None, str | None]:
        """(why this cell cannot run yet, what to tell the cells that use what it makes), or (None, None). A name that
        this very cell would have rebound does not hold it back while its earlier value is there: Jupyter's kernel
        transforms each cell twice (ipykernel's do_execute, then run_cell), and a skipped cell is run again once its
        exercise is done."""
        made_here, defined_here = set(), {}  # defined_here: a function this cell defines → the names its body reads
        for node in tree.body:
            for name in _loaded_names(node):
                if name in made_here and name not in defined_here:
                    continue
                # a function this cell defines is judged by its new body, not by the notebook's older one
                direct = [] if name in defined_here else [(name, "")]
                for used, via in direct + [(inner, f"{name}, which calls ") for inner in defined_here.get(name, ())]:
                    cause, maker = self.missing.get(used, (None, None))
                    if cause is not None and not (maker == source and used in self.user_ns):
                        return f"it uses {via}{used}, made by {cause}", cause
                    why = self.unfinished(used)
                    if why:
                        return f"it needs {via}{why}", f"a cell that needs {via}{why}"
            made_here |= _assigned_names(ast.Module(body=[node], type_ignores=[]))
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                defined_here[node.name] = sorted(_globals_read(node))
        return None, None


def _globals_read(func: ast.FunctionDef) -> set[str]:
    """The names a function's body reads from the notebook: not its parameters, not what it binds itself."""
    params = _parameters(func.args)
    local = {n.id for n in ast.walk(func) if isinstance(n, ast.Name) and not isinstance(n.ctx, ast.Load)}
    loads = {n.id for n in ast.walk(func) if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)}
    return loads - params - local - {func.name}


def _parameters(args: ast.arguments) -> set[str]:
    """The parameter names of a function or a lambda."""
    return {a.arg for a in [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg] if a}


def _raises_at_top_level(tree: ast.Module) -> bool:
    """A ``raise NotImplementedError`` that runs when the cell runs (not inside a def or class)."""
    for node in _outside_bodies(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
            if isinstance(exc, ast.Name) and exc.id == "NotImplementedError":
                return True
    return False


_SCOPES = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)


def _outside_bodies(node: ast.AST):
    """``node`` and what it holds, except what runs later: function and class bodies (their decorators,
    defaults and base classes run now, and are kept). A lambda's body is kept: one handed to a widget or a
    helper is called at once."""
    stack = [node]
    while stack:
        n = stack.pop()
        yield n
        if isinstance(n, _SCOPES):
            args = n.args if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)) else None
            stack.extend(getattr(n, "decorator_list", []) + getattr(n, "bases", []) +
                         (args.defaults + [d for d in args.kw_defaults if d is not None] if args else []))
        else:
            stack.extend(ast.iter_child_nodes(n))


def _loaded_names(node: ast.AST) -> list[str]:
    """Names a statement reads from the notebook when it runs: not those it binds itself before reading them
    (a loop's target, a ``with … as`` name, an assignment earlier in a loop body) or in a comprehension, not
    a function passed straight to ``check(...)`` (the check reports a stub itself), and no builtins."""
    nodes = list(_outside_bodies(node))
    skip = set()
    for n in nodes:
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "check":
            skip |= {id(a) for a in n.args[1:] if isinstance(a, ast.Name)}
    local = {t.id for n in nodes if isinstance(n, ast.comprehension)
             for t in ast.walk(n.target) if isinstance(t, ast.Name)}
    local |= {name for n in nodes if isinstance(n, ast.Lambda) for name in _parameters(n.args)}
    bound = _bound_at(nodes)
    loads = [n for n in nodes if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load) and id(n) not in skip]
    loads += [n.target for n in nodes if isinstance(n, ast.AugAssign) and isinstance(n.target, ast.Name)]  # x += …
    names = sorted(((n.lineno, n.col_offset), n.id) for n in loads)
    read = [name for where, name in names if name not in local and not (name in bound and bound[name] <= where)]
    return [n for n in dict.fromkeys(read) if not hasattr(builtins, n)]


def _bound_at(nodes: list[ast.AST]) -> dict[str, tuple[int, int]]:
    """(line, column) where a statement first binds each name: after what the binding evaluates first (an
    assignment's value, a loop's iterable, a with's context), so ``x = x + 1`` and ``for x in f(x)`` read x."""
    bound = {}
    for n in nodes:
        if isinstance(n, (ast.Assign, ast.AnnAssign, ast.AugAssign, ast.NamedExpr)):
            targets, after = getattr(n, "targets", [getattr(n, "target", None)]), n
        elif isinstance(n, (ast.For, ast.AsyncFor)):
            targets, after = [n.target], n.iter
        elif isinstance(n, ast.withitem) and n.optional_vars is not None:
            targets, after = [n.optional_vars], n.context_expr
        else:
            continue
        where = (after.end_lineno, after.end_col_offset)
        for name in (t for target in targets for t in ast.walk(target)):
            if isinstance(name, ast.Name) and isinstance(name.ctx, ast.Store):
                bound[name.id] = min(bound.get(name.id, where), where)
    return bound


def _assigned_names(tree: ast.AST) -> set[str]:
    """Names a cell binds in the notebook's namespace (assignments, defs, classes, imports, for targets)."""
    names = set()
    for node in _outside_bodies(tree):
        if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
            names.add(node.id)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def load_ipython_extension(ipython) -> None:
    """``%load_ext kfkit.exercise_guard``: install the guard (one at most, also after ``%reload_ext``)."""
    unload_ipython_extension(ipython)
    ipython.input_transformers_post.append(ExerciseGuard(ipython.user_ns))


def unload_ipython_extension(ipython) -> None:
    ipython.input_transformers_post[:] = [t for t in ipython.input_transformers_post
                                          if not getattr(t, "is_exercise_guard", False)]
