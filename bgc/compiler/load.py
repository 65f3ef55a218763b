"""Stage 1: path -> :class:`~bgc.ir.RawModel`.

Reads a YAML model with PyYAML's safe composer (no Python tags, nothing is
executed) and turns the node tree into plain data while recording the
``file:line:column`` of every node, so later stages can point at the source.
Mapping keys are kept as the text written (bond ``4`` has key ``'4'``), so
the data is JSON-like for schema validation. Duplicate mapping keys, which
YAML silently overwrites, are reported here: a duplicate element name or bond
number is an error, not a surprise.

Numbers are read as YAML 1.2 reads them: ``1e5``, ``2.5e-3`` and ``-.5`` are
floats (PyYAML follows YAML 1.1, where a float needs a dot and a signed
exponent, and reads them as text). A quoted number stays text, and the
validator says so.

The file is data from outside: it must be a regular file (not a FIFO or a
device, which could block or never end), its size is checked before it is read,
alias expansion is bounded, and text that is not valid Unicode (a lone
surrogate escape ``\\ud800``, an escape beyond U+10FFFF) is a located error.
"""

from __future__ import annotations

import hashlib
import re
import stat
from pathlib import Path
from typing import Any

import yaml

from ..errors import ErrorGroup, LoadError, SourceLoc
from ..ir import RawModel

#: Refuse documents larger than this: a bond graph is small; a giant file is a mistake or an attack.
MAX_BYTES = 2_000_000
#: Refuse alias expansion beyond this many nodes ("billion laughs").
MAX_NODES = 200_000
#: The only tags a mapping or a list may carry (the implicit ones): no ``!!python/...``.
_COLLECTION_TAGS = frozenset({"tag:yaml.org,2002:map", "tag:yaml.org,2002:seq"})


class _Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2's floats (see the module docstring)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:\.[0-9]+(?:[eE][-+]?[0-9]+)?|[0-9]+\.[0-9]*(?:[eE][-+]?[0-9]+)?|[0-9]+[eE][-+]?[0-9]+)$"),
    list("-+.0123456789"))


def scalar_value(text: str) -> Any:
    """What bgc's YAML reader makes of ``text`` written unquoted as a value
    (None when it is not one plain scalar): ``'1e3'`` -> 1000.0."""
    try:
        node = yaml.compose(text, Loader=_Loader)
    except (yaml.YAMLError, ValueError, OverflowError):
        return None
    if not isinstance(node, yaml.ScalarNode):
        return None
    try:
        return _Loader("").construct_object(node, deep=True)
    except (yaml.YAMLError, ValueError, OverflowError):
        return None


def declares_modes(path: str | Path) -> bool:
    """Whether the model file declares modes (a hybrid bond graph), read by
    the loader only: what a command asks before it takes the single-mode
    path (no compiler, no sympy). A file the loader refuses raises its error."""
    data = load(path).data
    return isinstance(data, dict) and "modes" in data


def load(path: str | Path) -> RawModel:
    """Read a model file.

    Raises
    ------
    LoadError
        The file is missing, unreadable, not a regular file, too large or not
        well-formed YAML.
    """
    name = str(path)
    p = Path(path)
    try:
        info = p.stat()
        if not stat.S_ISREG(info.st_mode):
            raise LoadError(f"{name}: not a regular file", None, "give a model file (YAML)")
        if info.st_size > MAX_BYTES:
            raise LoadError(f"{name}: file is {info.st_size} bytes, more than {MAX_BYTES}", None,
                            "a bond-graph model should be far smaller")
        with open(p, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise LoadError(f"{name}: no such file", None, "check the path") from None
    except IsADirectoryError:
        raise LoadError(f"{name}: is a folder", None, "give a model file (YAML)") from None
    except OSError as exc:
        raise LoadError(f"{name}: cannot read: {exc.strerror}", None, "check the path and its permissions") from None
    if len(raw) > MAX_BYTES:
        raise LoadError(f"{name}: file is more than {MAX_BYTES} bytes", None,
                        "a bond-graph model should be far smaller")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise LoadError(f"not UTF-8 text (byte {exc.start})", SourceLoc(name, 1, 1),
                        "save the file as UTF-8") from None
    return loads(text, name)


def loads(text: str, name: str = "<string>") -> RawModel:
    """Parse YAML text; ``name`` is used in locations."""
    loader = None
    try:
        loader = _Loader(text)  # its reader refuses control characters at once
        node = loader.get_single_node()
    except (ValueError, OverflowError):  # an escape beyond U+10FFFF (\UFFFFFFFF): not marked
        mark = loader.get_mark()
        raise LoadError("an escape sequence names no Unicode character", SourceLoc(name, mark.line + 1, mark.column + 1),
                        "write a character from U+0000 to U+10FFFF") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        loc = SourceLoc(name, mark.line + 1, mark.column + 1) if mark else SourceLoc(name, 1, 1)
        raise LoadError(f"YAML syntax error: {exc.problem or exc.context}", loc,
                        "fix the YAML syntax at this place") from None
    except yaml.reader.ReaderError as exc:  # a control character such as NUL: not marked
        raise LoadError(f"character {_char_name(exc.character)} is not allowed in YAML",
                        _position(text, name, exc.position),
                        "delete it: a model file is plain text") from None
    except yaml.YAMLError as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise LoadError(f"YAML error: {first}", SourceLoc(name, 1, 1),
                        "fix the YAML syntax: see docs/format.md") from None
    except RecursionError:
        raise LoadError("YAML is nested too deeply", SourceLoc(name, 1, 1),
                        "a model needs only a few levels of nesting") from None
    finally:
        if loader is not None:
            loader.dispose()
    if node is None:
        raise LoadError("the file is empty", SourceLoc(name, 1, 1),
                        "write a model: see docs/format.md")
    try:
        return _Walker(name).run(node, hashlib.sha256(text.encode("utf-8")).hexdigest())
    except RecursionError:
        raise LoadError("YAML is nested too deeply", SourceLoc(name, 1, 1),
                        "a model needs only a few levels of nesting") from None


#: What YAML counts as a line break (as its reader does: a CR only when no LF follows).
_BREAK = re.compile("\r\n|[\n\r\x85\u2028\u2029]")


def _position(text: str, name: str, position: int) -> SourceLoc:
    """The place of a character offset in ``text``, lines counted as YAML counts them."""
    before = text[: max(0, min(position, len(text)))]
    breaks = list(_BREAK.finditer(before))
    start = breaks[-1].end() if breaks else int(text.startswith("\ufeff"))  # a BOM is no column
    return SourceLoc(name, len(breaks) + 1, len(before) - start + 1)


def _char_name(character: object) -> str:
    """``#x0000 (NUL)`` for a code point."""
    if isinstance(character, str) and character:
        character = ord(character[0])
    if not isinstance(character, int):
        return "a special character"
    return f"#x{character:04x}" + (" (NUL)" if character == 0 else "")


class _Walker:
    def __init__(self, name: str):
        self.name = name
        self.constructor = _Loader("")  # only its scalar constructors are used
        self.locations: dict[tuple, SourceLoc] = {}
        self.key_locations: dict[tuple, SourceLoc] = {}
        self.errors: list[LoadError] = []
        self.count = 0
        self.open: set[int] = set()  # ids of the collection nodes being walked (recursive aliases)

    def run(self, node: yaml.Node, sha256: str) -> RawModel:
        data = self.walk(node, ())
        if self.errors:
            raise ErrorGroup(self.errors)
        return RawModel(self.name, data, self.locations, self.key_locations, sha256)

    def mark(self, node: yaml.Node) -> SourceLoc:
        return SourceLoc(self.name, node.start_mark.line + 1, node.start_mark.column + 1)

    def walk(self, node: yaml.Node, path: tuple) -> Any:
        self.count += 1
        if self.count > MAX_NODES:
            raise LoadError(f"more than {MAX_NODES} YAML nodes (alias expansion?)", self.mark(node),
                            "do not use anchors and aliases to multiply content")
        self.locations[path] = self.mark(node)
        if isinstance(node, (yaml.MappingNode, yaml.SequenceNode)):
            if node.tag not in _COLLECTION_TAGS:
                self.errors.append(LoadError(f"YAML tag '{node.tag}' is not allowed", self.mark(node),
                                             "remove the tag: a model is plain mappings, lists and scalars"))
                return None
            if id(node) in self.open:
                raise LoadError("recursive YAML alias", self.mark(node),
                                "an alias must not refer to a node that contains it")
            self.open.add(id(node))
            try:
                return self.collection(node, path)
            finally:
                self.open.discard(id(node))
        return self.scalar(node)

    def collection(self, node: yaml.Node, path: tuple) -> Any:
        if isinstance(node, yaml.MappingNode):
            try:
                self.constructor.flatten_mapping(node)
            except yaml.MarkedYAMLError as exc:  # a merge key '<<' on something that is not a mapping
                mark = exc.problem_mark or exc.context_mark
                where = SourceLoc(self.name, mark.line + 1, mark.column + 1) if mark else self.mark(node)
                self.errors.append(LoadError(f"bad merge key '<<': {exc.problem or exc.context}", where,
                                             "merge only mappings, or remove the '<<' key"))
                return None
            out: dict = {}
            for key_node, value_node in node.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    self.errors.append(LoadError("mapping keys must be plain names or numbers",
                                                 self.mark(key_node), "write a scalar key"))
                    continue
                key = key_node.value  # keys stay text as written: bond 4 is the key '4'
                if not _valid_unicode(key):
                    self.errors.append(LoadError("a key holds an invalid Unicode character (a lone surrogate)",
                                                 self.mark(key_node), "remove the \\u escape"))
                    continue
                if key in out:
                    first = self.key_locations[path + (key,)]
                    self.errors.append(LoadError(
                        f"duplicate key '{key}' (first at line {first.line})", self.mark(key_node),
                        "names and bond numbers must be unique: rename or remove one"))
                    continue
                self.key_locations[path + (key,)] = self.mark(key_node)
                out[key] = self.walk(value_node, path + (key,))
            return out
        return [self.walk(item, path + (i,)) for i, item in enumerate(node.value)]

    def scalar(self, node: yaml.Node) -> Any:
        try:
            value = self.constructor.construct_object(node, deep=True)
            if isinstance(value, str) and not _valid_unicode(value):
                self.errors.append(LoadError("text holds an invalid Unicode character (a lone surrogate such as "
                                             "\\ud800)", self.mark(node), "remove the \\u escape"))
                return None
            return value
        except yaml.MarkedYAMLError as exc:
            what = exc.problem or exc.context or "cannot read the value"
        except (yaml.YAMLError, ValueError, OverflowError) as exc:  # e.g. the date 2001-13-45
            what = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self.errors.append(LoadError(f"bad value: {what}", self.mark(node), "fix this value"))
        return None


def _valid_unicode(text: str) -> bool:
    """Whether ``text`` can be written as UTF-8 (no lone surrogates)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True
