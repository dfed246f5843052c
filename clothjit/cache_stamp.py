"""numba's on-disk cache made stale when any clothpipe module a kernel's file imports changes.

numba (0.68) stamps a cached kernel with a hash of its own source file only
(`_SourceFileBackedLocatorMixin.get_source_stamp`). A kernel that calls a jitted function of
another file inlines or links that function's code, so when only the other file changes
(an edit, or an upgrade of clothpipe that changes a helper module but not its callers) the
old machine code keeps being loaded (seen: integrators/vbd.py's `_sweep` ran the old
physics/vbd_contact.py `contact_terms` until NUMBA_CACHE_DIR was emptied).

Here a kernel whose file lies in one of clothpipe's packages (pipeline, shading, clothjit:
`PACKAGES`) is stamped with a hash of its file and every file of those packages it imports,
transitively (`import_closure`). Changing any of them recompiles the kernel once; a kernel
elsewhere keeps numba's stamp. An unrelated edit in the closure recompiles too (the closure
is a file's imports, not the functions a kernel calls): correct, rarely needed.

The hook is numba's own way of choosing where and how a function is cached: subclasses of
its three source-file locators (numba's cache folder, `__pycache__` beside the file, the
user-wide folder: editable and site-packages installs alike), ahead of numba's in
`CacheImpl._locator_classes`, that accept project files only and differ only in the stamp.
The cache folders and file names stay numba's, and clothjit's locked save and load
(clothjit/__init__.py) act on them unchanged. NUMBA_CACHE_LOCATOR_CLASSES, which replaces
that list, leaves numba's behaviour.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import re
import sys
from collections.abc import Iterator

from numba.core import caching

__all__ = ["LOCATORS", "PACKAGES", "ROOTS", "import_closure", "install", "stamp", "track",
           "untrack"]

#: clothpipe's packages: name -> folder (found on first use: `_roots`)
PACKAGES = ("pipeline", "shading", "clothjit")
#: extra packages tracked like clothpipe's (`track`): name -> folder
ROOTS: dict[str, str] = {}

# An import statement from the start of its line through its closing parenthesis or its
# backslash continuations: found from each "import" in the text, not by ast.parse, which
# takes 0.37 s for the 23k lines of the three packages on this machine (this scan: 1-2 ms).
# An import after `;` or on the line of an `if` or `try` is not seen (there is none here);
# a docstring line that reads like an import only adds a file to the closure.
_STATEMENT = re.compile(
    r"[ \t]*(?:from[ \t]+([.\w]+)[ \t]+import\b[ \t]*(\([^)]*\)|(?:[^\n]*\\\n)*[^\n]*)"
    r"|import[ \t]+((?:[^\n]*\\\n)*[^\n]*))")


@functools.cache
def _roots() -> dict[str, str]:
    """Each tracked package's folder, normalised (importlib finds a top-level package without
    importing it: editable installs and site-packages alike)."""
    roots = {}
    for name in PACKAGES:
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.submodule_search_locations:
            roots[name] = os.path.realpath(next(iter(spec.submodule_search_locations)))
    roots.update((name, os.path.realpath(folder)) for name, folder in ROOTS.items())
    return roots


def track(folder: str) -> None:
    """Track the package in `folder` (its name is the folder's) like clothpipe's own: its
    kernels' stamps cover its imports. For packages built on clothjit, and the tests."""
    folder = os.path.realpath(folder)
    ROOTS[os.path.basename(folder)] = folder
    _forget()


def untrack(folder: str) -> None:
    """Stop tracking the package `track` tracked in `folder`."""
    ROOTS.pop(os.path.basename(os.path.realpath(folder)), None)
    _forget()


def _forget() -> None:
    """Empty every memo (the tracked folders changed)."""
    for memo in (_roots, _module_name, _listing, _file_of, _imports, import_closure,
                 _file_digest, stamp):
        memo.cache_clear()


@functools.cache
def _module_name(path: str) -> tuple[str, ...] | None:
    """The dotted name of the tracked module in file `path` (`__init__` dropped), or None."""
    path = os.path.realpath(path)
    for name, folder in _roots().items():
        if path.startswith(folder + os.sep) and path.endswith(".py"):
            parts = (name, *os.path.relpath(path[:-3], folder).split(os.sep))
            return parts[:-1] if parts[-1] == "__init__" else parts
    return None


@functools.cache
def _listing(folder: str) -> frozenset[str]:
    """The names in `folder` (one look per folder, not a stat per name tried)."""
    try:
        return frozenset(os.listdir(folder))
    except OSError:
        return frozenset()


@functools.cache
def _file_of(module: tuple[str, ...]) -> str | None:
    """The file of tracked module `module` (a module or a package's `__init__.py`), or None."""
    folder = _roots().get(module[0])
    if folder is None:
        return None
    folder = os.path.join(folder, *module[1:-1])
    name = module[-1] if len(module) > 1 else ""
    if name + ".py" in _listing(folder):
        return os.path.join(folder, name + ".py")
    package = os.path.join(folder, name) if name else folder
    if "__init__.py" in _listing(package):
        return os.path.join(package, "__init__.py")
    return None


def _names(text: str) -> list[str]:
    """The names an import statement's tail lists (`a.b as c, d` -> a.b, d)."""
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    text = text.split(";")[0].replace("(", " ").replace(")", " ").replace("\\\n", " ")
    return [part.split(None, 1)[0] for part in text.split(",") if part.strip()]


def _statements(source: str) -> Iterator[tuple[str | None, str | None, str | None]]:
    """(module, names) of each `from module import names`, (None, None, names) of each
    `import names` in `source`."""
    at = source.find("import")
    while at != -1:
        match = _STATEMENT.match(source, source.rfind("\n", 0, at) + 1)
        if match is not None and match.end() > at:
            yield match.groups()
            at = match.end()
        else:
            at += len("import")
        at = source.find("import", at)


@functools.cache
def _imports(path: str) -> frozenset[str]:
    """The tracked files that the statements `import` and `from ... import` of `path` name:
    for `import a.b`, a and a.b; for `from p import n`, p and p.n if that is a module;
    relative imports resolved against the file's package."""
    module = _module_name(path)
    if module is None:
        return frozenset()
    package = module if path.endswith("__init__.py") else module[:-1]
    with open(path, encoding="utf-8", errors="replace") as fh:
        source = fh.read()
    modules: list[tuple[str, ...]] = []
    for origin, listed, imported in _statements(source):
        if imported is not None:
            for name in _names(imported):
                parts = tuple(name.split("."))
                modules += [parts[:k] for k in range(1, len(parts) + 1)]
            continue
        level = len(origin) - len(origin.lstrip("."))
        base = tuple(p for p in origin[level:].split(".") if p)
        if level:
            if level - 1 > len(package):
                continue
            base = package[:len(package) - level + 1] + base
        if base:
            modules.append(base)
            modules += [base + (name,) for name in _names(listed) if name != "*"]
    return frozenset(f for f in map(_file_of, modules) if f is not None)


@functools.cache
def import_closure(path: str) -> frozenset[str]:
    """`path` and every tracked file it imports, transitively (once per process)."""
    path = os.path.realpath(path)
    seen, todo = {path}, [path]
    while todo:
        for found in _imports(todo.pop()):
            if found not in seen:
                seen.add(found)
                todo.append(found)
    return frozenset(seen)


@functools.cache
def _file_digest(path: str) -> bytes:
    """The module name of tracked file `path` (so that a stamp does not depend on where the
    package is installed) and the sha256 of its contents, once per process."""
    with open(path, "rb") as fh:
        contents = fh.read()
    return ".".join(_module_name(path) or (path,)).encode() + hashlib.sha256(contents).digest()


@functools.cache
def stamp(path: str) -> bytes:
    """sha256 of the names and contents of `path`'s import closure, in name order."""
    return hashlib.sha256(b"".join(sorted(map(_file_digest, import_closure(path))))).digest()


class _ClosureStamp:
    """A numba source-file locator for tracked files only, stamped with `stamp`."""

    _py_file: str

    def get_source_stamp(self) -> bytes:
        if getattr(sys, "frozen", False):
            return super().get_source_stamp()  # numba stamps a frozen program's executable
        return stamp(self._py_file)

    @classmethod
    def from_function(cls, py_func, py_file: str) -> caching._CacheLocator | None:
        if _module_name(py_file) is None:
            return None
        return super().from_function(py_func, py_file)


LOCATORS = tuple(type(f"Closure{base.__name__}", (_ClosureStamp, base), {})
                 for base in (caching.UserProvidedCacheLocator, caching.InTreeCacheLocator,
                              caching.UserWideCacheLocator))


def install() -> None:
    """Put LOCATORS ahead of numba's (once), in numba's order of preference."""
    current = caching.CacheImpl._locator_classes
    if not set(LOCATORS) & set(current):
        caching.CacheImpl._locator_classes = [*LOCATORS, *current]
