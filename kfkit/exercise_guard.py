"""Run All goes to the end of a hand-out: cells that need an exercise not done yet say so and step aside.

A hand-out's exercises are stubs, exactly as ``kfkit make-labs`` wrote them (:func:`kfkit.authoring.is_stub`: the
statement ``raise NotImplementedError()`` in the function's own body, with no return before it; a finished function
that raises or catches NotImplementedError is not one). Without this, Run All stops at the first cell that calls one,
and a student who opened lab 00 to record data, or wants to see lab 04's figures before writing the EKF, never
reaches the rest. Loaded in a lab's first cell::

    %load_ext kfkit.exercise_guard

before each cell runs, IPython hands its code to :class:`ExerciseGuard`, which replaces the cell by a one-line
note when the cell

- is an unfinished exercise itself (the stub's raise among the cell's own statements): "fill in this cell";
- uses a function that is still a stub, or that calls one (followed through your own functions, the names they read
  from the notebook (not their parameters, their locals, an attribute), the functions their closure holds and the one
  they wrap, into a function the same cell defines, and into a lambda handed on), or a name that only a skipped cell
  would have made: "needs kf_predict (not written yet)". A name is missing only while nothing that ran has bound
  it since: a function's ``global x0``, ``globals().update(…)`` or ``exec`` that ran makes it there.

Everything else runs as usual, so the lab's own figures, the capture panel and every cell that needs no
exercise run. ``check("…", f)`` and ``check("…", answer=f)`` cells always run (unless ``f`` does not exist at
all): the check itself says "not attempted yet". When a cell that defines a function is skipped, the notebook's
older definition is set aside (:class:`StaleDefinition`), so that its check says "stale" instead of passing code
the student has since changed. A solution notebook, with nothing unfinished, runs exactly as without the guard.
"""

from __future__ import annotations

import ast
import builtins
import dis
import functools
import inspect
import textwrap
import types
from typing import NamedTuple

from kfkit.authoring import is_stub

NOTE = "⏭  skipped: {why}. Run this cell again when that is done."

_DEFS = (ast.FunctionDef, ast.AsyncFunctionDef)
_COMPREHENSIONS = (ast.ListComp, ast.SetComp, ast.DictComp, ast.GeneratorExp)
_SCOPES = _DEFS + (ast.Lambda, ast.ClassDef) + _COMPREHENSIONS
_ABSENT = object()  # what a missing name held when its cell was skipped, if nothing


class StaleDefinition(NotImplementedError):
    """Raised by a function the guard set aside: the cell that defines it anew was skipped, and the older definition
    must not pass its check for code the student has changed since. ``check`` knows it by ``stale_definition`` (not
    by class: ``%reload_ext`` makes a new class)."""

    stale_definition = True


class _Missing(NamedTuple):
    cause: str  # why the skipped cell did not make it
    source: str  # that cell's code
    held: object  # the name's value when that cell was skipped (_ABSENT: none): missing while it still holds it


class ExerciseGuard:
    """The IPython input transformer (see the module doc); ``user_ns`` is the notebook's namespace."""

    is_exercise_guard = True  # how (un)loading finds it, also across %reload_ext (a new class object)

    def __init__(self, user_ns: dict):
        self.user_ns = user_ns
        self.missing: dict[str, _Missing] = {}

    def unfinished(self, name: str) -> str | None:
        """Why the notebook's ``name`` cannot run yet (a stub, a definition set aside, or a function that calls
        one), or None."""
        return self._why_unfinished(name, self.user_ns.get(name), set())

    def __call__(self, lines: list[str]) -> list[str]:
        source = "".join(lines)
        try:
            tree = ast.parse(source)
        except SyntaxError:  # let IPython report it as usual
            return lines
        made = assigned_names(tree.body)
        if is_stub(tree.body):
            why, cause = (
                "this cell is an exercise: replace '# YOUR CODE HERE' and the raise below it with your code",
                "an exercise cell not filled in yet",
            )
        else:
            why, cause = self._needs(tree, source)
        if why is None:
            for name in made:
                self.missing.pop(name, None)
            return lines
        self._skip(tree, source, made, cause)
        return [f"print({NOTE.format(why=why)!r})\n"]

    def _skip(self, tree: ast.Module, source: str, made: set[str], cause: str) -> None:
        """Record what the skipped cell would have made (the latest reason: the one before may be done by now), and
        set aside the notebook's older definitions of the functions it defines."""
        defined = _functions_defined(tree.body) | {n for n in made if self._notebook_function(self.user_ns.get(n))}
        for name in defined:
            self.user_ns[name] = _set_aside(name, cause)
        for name in made:
            self.missing[name] = _Missing(cause, source, self.user_ns.get(name, _ABSENT))
        # what its functions would have bound with a `global` statement: missing only where nothing is
        for name in self._global_stores(tree) - made - set(self.user_ns):
            self.missing[name] = _Missing(cause, source, _ABSENT)

    def _still_missing(self, name: str) -> _Missing | None:
        """The record of ``name`` if a skipped cell would have made it and nothing that ran has bound it since."""
        entry = self.missing.get(name)
        if entry is not None and self.user_ns.get(name, _ABSENT) is not entry.held:
            del self.missing[name]  # a global statement, globals().update, exec … that ran has bound it
            entry = None
        return entry

    def _needs(self, tree: ast.Module, source: str) -> tuple[str | None, str | None]:
        """(why this cell cannot run yet, what to tell the cells that use what it makes), or (None, None). A name that
        this very cell would have rebound does not hold it back while its earlier value is there: Jupyter's kernel
        transforms each cell twice (ipykernel's do_execute, then run_cell), and a skipped cell is run again once its
        exercise is done."""
        made_here: set[str] = set()
        defined_here: dict[str, ast.FunctionDef] = {}  # a function this cell defines is judged by its new body
        for statement in tree.body:
            for name, for_check in _reads_now(statement):
                if name in made_here and name not in defined_here:
                    continue
                found = self._blocked(name, "", for_check, source, defined_here, set())
                if found:
                    return found
            made_here |= assigned_names([statement])
            defined_here.update((n.name, n) for n in _in_scope([statement]) if isinstance(n, _DEFS))
        return None, None

    def _blocked(self, name, via, for_check, source, defined_here, seen) -> tuple[str, str] | None:
        """(note, cause) if using ``name`` (reached ``via`` functions this cell defines) cannot work yet. ``for_check``:
        it is handed to check(…), which reports a stub itself: only a name that does not exist holds it back."""
        if name in defined_here:
            node = defined_here[name]
            if is_stub(node.body) and not for_check:
                return f"it needs {via}{name} (not written yet)", f"a cell that needs {via}{name} (not written yet)"
            seen = seen | {name}
            for inner in sorted(_global_reads(node) - seen):
                found = self._blocked(inner, f"{via}{name}, which calls ", for_check, source, defined_here, seen)
                if found:
                    return found
            return None
        if hasattr(builtins, name) and name not in self.user_ns and name not in self.missing:
            return None
        entry = self._still_missing(name)
        if (
            entry is not None
            and not (entry.source == source and name in self.user_ns)
            and not (for_check and name in self.user_ns)
        ):
            return f"it uses {via}{name}, made by {entry.cause}", entry.cause
        why = None if for_check else self.unfinished(name)
        if why:
            return f"it needs {via}{why}", f"a cell that needs {via}{why}"
        return None

    def _why_unfinished(self, name: str, value, seen: set[int]) -> str | None:
        if isinstance(value, functools.partial):
            value = value.func
        value = getattr(value, "__func__", value)  # a bound method
        if isinstance(value, types.FunctionType) and isinstance(getattr(value, "set_aside", None), str):
            return f"{name} ({value.set_aside})"
        if not self._notebook_function(value) or id(value) in seen:
            return None
        seen.add(id(value))
        if _is_stub_function(value.__code__):
            return f"{name} (not written yet)"
        for inner_name, inner in self._calls(value):
            why = self._why_unfinished(inner_name, inner, seen)
            if why:
                return why if inner_name == name else f"{name}, which calls {why}"
        return None

    def _notebook_function(self, value) -> bool:
        return isinstance(value, types.FunctionType) and value.__globals__ is self.user_ns

    def _calls(self, func: types.FunctionType):
        """(name, value) of what a notebook function may call: the notebook's names its code (and the code nested in
        it) reads as globals, the functions its closure holds, the function it wraps (functools.wraps)."""
        for name in sorted(_code_global_reads(func.__code__)):
            if name in self.user_ns:
                yield name, self.user_ns[name]
        for var, cell in zip(func.__code__.co_freevars, func.__closure__ or ()):
            try:
                value = cell.cell_contents
            except ValueError:  # an empty cell
                continue
            yield getattr(value, "__name__", var), value
        wrapped = func.__dict__.get("__wrapped__")
        if wrapped is not None:
            yield getattr(wrapped, "__name__", func.__name__), wrapped

    def _global_stores(self, tree: ast.Module) -> set[str]:
        """Names the functions a cell defines or calls bind with a ``global`` statement (followed like stubs)."""
        names = {n for node in ast.walk(tree) if isinstance(node, ast.Global) for n in node.names}
        todo = [self.user_ns.get(name) for statement in tree.body for name, _ in _reads_now(statement)]
        seen = set()
        while todo:
            value = todo.pop()
            if self._notebook_function(value) and id(value) not in seen:
                seen.add(id(value))
                names |= _code_global_stores(value.__code__)
                todo.extend(inner for _, inner in self._calls(value))
        return names


def _set_aside(name: str, cause: str) -> types.FunctionType:
    """What stands for the function ``name`` while the cell that defines it anew is skipped, as ``cause``: calling it,
    or checking it, says so."""
    message = (
        f"the cell that defines {name} was skipped, as {cause}. The {name} defined before it is set aside; "
        "run that cell again once that is done, then this one"
    )

    def stand_in(*args, **kwargs):
        raise StaleDefinition(message)

    stand_in.__name__ = stand_in.__qualname__ = name
    stand_in.__module__ = "__main__"  # it stands in the notebook for the notebook's function
    stand_in.__doc__ = message
    stand_in.set_aside = "its cell was skipped"
    return stand_in


def _is_stub_function(code: types.CodeType) -> bool:
    """A notebook function is a stub when its source (IPython keeps each cell's in linecache) is one
    (:func:`kfkit.authoring.is_stub`). Without a source (a function made by exec) it is not."""
    # the stub's raise reads NotImplementedError; equal code objects may come from different files
    return "NotImplementedError" in code.co_names and _is_stub_source(code, code.co_filename)


@functools.cache
def _is_stub_source(code: types.CodeType, filename: str) -> bool:
    try:
        tree = ast.parse(textwrap.dedent("".join(inspect.getsourcelines(code)[0])))
    except (OSError, TypeError, SyntaxError):
        return False
    node = tree.body[0] if tree.body else None
    return isinstance(node, _DEFS) and node.name == code.co_name and is_stub(node.body)


_GLOBAL_LOADS = {"LOAD_GLOBAL", "LOAD_NAME", "LOAD_FROM_DICT_OR_GLOBALS"}


@functools.cache
def _code_global_reads(code: types.CodeType) -> frozenset[str]:
    """The names ``code`` and the code nested in it read from the module's namespace: not parameters, locals or
    names of an enclosing function (fast and cell loads), not attributes (``obj.r``)."""
    names = {i.argval for i in dis.get_instructions(code) if i.opname in _GLOBAL_LOADS}
    return frozenset(names.union(*(_code_global_reads(c) for c in code.co_consts if isinstance(c, types.CodeType))))


@functools.cache
def _code_global_stores(code: types.CodeType) -> frozenset[str]:
    names = {i.argval for i in dis.get_instructions(code) if i.opname == "STORE_GLOBAL"}
    return frozenset(names.union(*(_code_global_stores(c) for c in code.co_consts if isinstance(c, types.CodeType))))


def _parameters(args: ast.arguments) -> set[str]:
    """The parameter names of a function or a lambda."""
    return {a.arg for a in [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg] if a}


def _outside(scope: ast.AST) -> list[ast.AST]:
    """What a def, lambda, class or comprehension evaluates where it stands: decorators, defaults, base classes,
    a comprehension's first iterable."""
    if isinstance(scope, (*_DEFS, ast.Lambda)):
        return [
            *getattr(scope, "decorator_list", []),
            *scope.args.defaults,
            *[d for d in scope.args.kw_defaults if d is not None],
        ]
    if isinstance(scope, ast.ClassDef):
        return [*scope.decorator_list, *scope.bases, *[k.value for k in scope.keywords]]
    return [scope.generators[0].iter]


def _inside(scope: ast.AST) -> list[ast.AST]:
    """What runs in the scope's own namespace."""
    if isinstance(scope, (*_DEFS, ast.ClassDef)):
        return scope.body
    if isinstance(scope, ast.Lambda):
        return [scope.body]
    first, *rest = scope.generators
    parts = [first.target, *first.ifs, *[p for g in rest for p in (g.target, g.iter, *g.ifs)]]
    return parts + ([scope.key, scope.value] if isinstance(scope, ast.DictComp) else [scope.elt])


def _in_scope(nodes: list[ast.AST]):
    """Every node evaluated in the scope that runs ``nodes``: a def, lambda, class or comprehension in it is yielded
    itself, with what it evaluates where it stands, but not what runs inside it."""
    stack = list(reversed(nodes))
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(_outside(node) if isinstance(node, _SCOPES) else list(ast.iter_child_nodes(node))))


def _binds(node: ast.AST) -> set[str]:
    """The names one node binds in its scope."""
    if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
        return {node.id}
    if isinstance(node, (*_DEFS, ast.ClassDef)):
        return {node.name}
    if isinstance(node, (ast.Import, ast.ImportFrom)):
        return {(a.asname or a.name).split(".")[0] for a in node.names if a.name != "*"}
    if isinstance(node, (ast.ExceptHandler, ast.MatchAs, ast.MatchStar)) and node.name:
        return {node.name}
    if isinstance(node, ast.MatchMapping) and node.rest:
        return {node.rest}
    return set()


def _walrus_targets(comprehension: ast.AST) -> set[str]:
    """Names an assignment expression in a comprehension binds in the scope around it."""
    nodes = list(_in_scope(_inside(comprehension)))
    names = {n.target.id for n in nodes if isinstance(n, ast.NamedExpr)}
    return names.union(*(_walrus_targets(c) for c in nodes if isinstance(c, _COMPREHENSIONS)))


def _global_reads(scope: ast.AST, enclosing: frozenset = frozenset(), now: bool = False) -> set[str]:
    """The names a def, lambda, class or comprehension (with the scopes nested in it) reads from the notebook: not
    its parameters, not what it binds, not what an enclosing function binds (``enclosing``). ``now``: only what
    runs when it is reached (a lambda's body, a class body), not the defs in it."""
    nodes = list(_in_scope(_inside(scope)))
    declared = {n for node in nodes if isinstance(node, ast.Global) for n in node.names}
    free = {n for node in nodes if isinstance(node, ast.Nonlocal) for n in node.names}
    local = set().union(*(_binds(node) for node in nodes))
    if isinstance(scope, _COMPREHENSIONS):
        local -= {node.target.id for node in nodes if isinstance(node, ast.NamedExpr)}
    else:
        local |= set().union(*(_walrus_targets(c) for c in nodes if isinstance(c, _COMPREHENSIONS)))
    if isinstance(scope, (*_DEFS, ast.Lambda)):
        local |= _parameters(scope.args)
    local -= declared | free
    loads = [n.id for n in nodes if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)]
    loads += [n.target.id for n in nodes if isinstance(n, ast.AugAssign) and isinstance(n.target, ast.Name)]
    names = {n for n in loads if n in declared or not (n in local or n in free or n in enclosing)}
    around = enclosing if isinstance(scope, ast.ClassDef) else enclosing | local  # a class body encloses nothing
    for child in nodes:
        if isinstance(child, _SCOPES) and not (now and isinstance(child, _DEFS)):
            names |= _global_reads(child, frozenset(around), now)
    return names


def _reads_now(statement: ast.stmt) -> list[tuple[str, bool]]:
    """(name, handed to check) for each name a cell's statement reads from the notebook when it runs, in order: its
    own loads, and what the lambdas, comprehensions and classes in it read (a lambda handed to a widget or a helper
    is called at once), not a def's body; not a name it bound itself before reading it (a loop's target, a ``with …
    as`` name, an assignment earlier in a loop body). "Handed to check": only read as ``check(…)``'s answer."""
    nodes = list(_in_scope([statement]))
    for_check = {id(n) for call in nodes if _is_check(call) for n in ast.walk(_answer(call))}
    reads = [
        ((n.lineno, n.col_offset), n.id, id(n) in for_check)
        for n in nodes
        if isinstance(n, ast.Name) and isinstance(n.ctx, ast.Load)
    ]
    reads += [
        ((n.lineno, n.col_offset), n.target.id, False)
        for n in nodes
        if isinstance(n, ast.AugAssign) and isinstance(n.target, ast.Name)
    ]  # x += …
    for scope in (n for n in nodes if isinstance(n, _SCOPES) and not isinstance(n, _DEFS)):
        reads += [
            ((scope.lineno, scope.col_offset), name, id(scope) in for_check)
            for name in sorted(_global_reads(scope, now=True))
        ]
    walrus = [n for c in nodes if isinstance(c, _COMPREHENSIONS) for n in ast.walk(c) if isinstance(n, ast.NamedExpr)]
    bound = _bound_at(nodes + walrus)
    result: dict[str, bool] = {}
    for where, name, checked in sorted(reads):
        if not (name in bound and bound[name] <= where):
            result[name] = result.get(name, True) and checked
    return list(result.items())


def _is_check(node: ast.AST) -> bool:
    """A call of ``check(name, answer)`` with an answer (kfkit.checkpoints' check, however imported)."""
    if not isinstance(node, ast.Call):
        return False
    func = node.func.id if isinstance(node.func, ast.Name) else getattr(node.func, "attr", None)
    return func == "check" and _answer(node) is not None


def _answer(call: ast.Call) -> ast.AST | None:
    if len(call.args) > 1:
        return call.args[1]
    return next((k.value for k in call.keywords if k.arg == "answer"), None)


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


def assigned_names(statements: list[ast.stmt]) -> set[str]:
    """Names cell statements bind in the notebook's namespace (assignments, defs, classes, imports, loop targets …;
    not a comprehension's variables, a lambda's parameters or a function's locals)."""
    nodes = list(_in_scope(statements))
    names = set().union(*(_binds(n) for n in nodes))
    return names.union(*(_walrus_targets(c) for c in nodes if isinstance(c, _COMPREHENSIONS)))


def _functions_defined(statements: list[ast.stmt]) -> set[str]:
    """The functions cell statements define: ``def f``, and ``f = lambda …``."""
    nodes = list(_in_scope(statements))
    names = {n.name for n in nodes if isinstance(n, _DEFS)}
    return names | {
        t.id
        for n in nodes
        if isinstance(n, ast.Assign) and isinstance(n.value, ast.Lambda)
        for t in n.targets
        if isinstance(t, ast.Name)
    }


def load_ipython_extension(ipython) -> None:
    """``%load_ext kfkit.exercise_guard``: install the guard (one at most, also after ``%reload_ext``)."""
    unload_ipython_extension(ipython)
    ipython.input_transformers_post.append(ExerciseGuard(ipython.user_ns))


def unload_ipython_extension(ipython) -> None:
    ipython.input_transformers_post[:] = [
        t for t in ipython.input_transformers_post if not getattr(t, "is_exercise_guard", False)
    ]
