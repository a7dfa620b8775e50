"""One loader for every YAML document a user gives (scenario files, ``--set``, sweep specs, studies).

``load_yaml(text, where)`` reads plain YAML (mappings, lists, strings, numbers, booleans, null)
and refuses, as a one-line ``UserInputError`` naming ``where``:

- a document larger than ``MAX_BYTES``, or whose aliases expand to more than ``MAX_NODES``
  values (an "alias bomb": nine anchors of nine aliases each are 10^9 values, which any walk
  over the data would take hours to visit) or refer to themselves;
- mappings and lists nested more than ``MAX_DEPTH`` deep, in the text or through aliases: counted
  on the parser's events before any node is built (libyaml's composer recurses in C, and about
  25,000 levels, a 50 kB ``[[[[...]]]]``, ended the process with SIGSEGV);
- a mapping that names the same key twice (PyYAML keeps the last one silently);
- any tag (``!!python/object``, ``!Foo``): the data is plain YAML, except the local tags a caller
  names (``tags``: a scenario's ``engine: !Statics {}``), read as pydrake's ``yaml_load_data``
  reads a union's variant, the mapping with the tag under the key ``_tag``;
- text that is not YAML (the message names the line, the column and the kind of problem, and
  quotes nothing of the text: a file that is not what the user meant, a credentials file, must
  not end up in a log).

Plain scalars are read as YAML 1.2's core schema reads them, not as PyYAML's YAML 1.1 resolver:
``2.3e1``, ``1e-9``, ``.5`` and ``+1.`` are floats (YAML 1.1: the first two strings); ``010`` is
10 (YAML 1.1: octal 8), ``0o17`` 15, ``0x10`` 16; ``1:30``, ``1_6``, ``0b11``, ``on``, ``yes``
and ``2026-12-01`` are strings (YAML 1.1: 90, 16, 3, true, true and a date), which the schemas
then refuse where they want a number or a boolean. Only ``true`` and ``false`` (also ``True``,
``TRUE``, ``False``, ``FALSE``) are booleans. Everything else is PyYAML's ``SafeLoader``.

``load_typed(data, schema, where, defaults)`` builds a dataclass (or a pydrake config struct)
from data that ``load_yaml`` returned, with pydrake's ``yaml_load_typed`` (the project's one
way of typing YAML): the data is re-emitted as plain YAML (no aliases, no tags), so pydrake's
own parser sees exactly what was checked.
"""

from __future__ import annotations

import dataclasses
import math
import re
import sys
import typing
from pathlib import Path

import numpy as np

import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

from ballchain.infrastructure.errors import UserInputError, short_repr, quote_path
from ballchain.infrastructure.input_files import read_input_file

MAX_BYTES = 1_000_000  # a scenario file is a few kB; a sweep spec a few hundred lines
MAX_NODES = 100_000  # values after alias expansion (every use of an alias counts its anchor's values again)
MAX_DEPTH = 100  # mappings and lists nested in one another; the deepest shipped document (station.scenarios.yaml) has 7

# YAML 1.2 core schema floats (https://yaml.org/spec/1.2.2/#1023-core-schema), beside YAML 1.1's.
_FLOAT_12 = re.compile(r"^[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?$")
_BASE = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # libyaml's parser when built with it


class _Loader(_BASE):
    """SafeLoader with YAML 1.2's core schema (below) and duplicate-key refusal."""

    def construct_mapping(self, node, deep=False):
        if isinstance(node, MappingNode):
            seen = set()
            for key_node, _ in node.value:
                if key_node.tag == "tag:yaml.org,2002:merge":
                    continue  # "<<: *anchor" merges; an explicit key may override a merged one
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                except TypeError:  # an unhashable key: SafeConstructor reports it
                    break
                if duplicate:
                    raise _Duplicate(key, key_node.start_mark)
                seen.add(key)
        return super().construct_mapping(node, deep)


def _construct_int_1_2(loader, node):
    """A YAML 1.2 core-schema integer: decimal (leading zeros are decimal), ``0o`` octal, ``0x`` hex."""
    text = loader.construct_scalar(node)
    if text.startswith("0o"):
        return int(text[2:], 8)
    if text.startswith("0x"):
        return int(text[2:], 16)
    return int(text, 10)


# YAML 1.2's core schema in place of YAML 1.1's implicit booleans, integers, floats and dates
# (https://yaml.org/spec/1.2.2/#1032-tag-resolution); integers first: "12" matches both.
_YAML_1_1_ONLY = {f"tag:yaml.org,2002:{t}" for t in ("bool", "int", "float", "timestamp")}
_Loader.yaml_implicit_resolvers = {first: [(tag, rx) for tag, rx in resolvers if tag not in _YAML_1_1_ONLY]
                                   for first, resolvers in _BASE.yaml_implicit_resolvers.items()}
_Loader.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                              list("tTfF"))
_Loader.add_implicit_resolver("tag:yaml.org,2002:int", re.compile(r"^(?:[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+)$"),
                              list("-+0123456789"))
_Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+.0123456789"))
_Loader.add_implicit_resolver("tag:yaml.org,2002:float",
                              re.compile(r"^(?:[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"), list("-+."))
_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int_1_2)


def _tagged_loader(tags: frozenset):
    """``_Loader`` that reads the local tags in ``tags`` as pydrake's ``yaml_load_data`` does: a
    tagged mapping as the mapping with its tag under ``_tag`` (``!Statics {}`` is
    ``{"_tag": "!Statics"}``), a tag alone (an empty scalar) as the empty mapping's; any other tag,
    or a tag on a list or a value, is refused as before."""

    class TaggedLoader(_Loader):
        pass

    def construct(loader, suffix, node):
        if node.tag not in tags or not (isinstance(node, MappingNode)
                                        or (isinstance(node, ScalarNode) and node.value == "")):
            raise yaml.constructor.ConstructorError(
                None, None, f"could not determine a constructor for the tag {node.tag!r}", node.start_mark)
        value = loader.construct_mapping(node, deep=True) if isinstance(node, MappingNode) else {}
        return {**value, "_tag": node.tag}

    TaggedLoader.add_multi_constructor("!", construct)
    return TaggedLoader


class _Duplicate(Exception):
    def __init__(self, key, mark):
        super().__init__(key)
        self.key, self.mark = key, mark


def _at(mark) -> str:
    return f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""


def _too_deep(where: str, mark) -> UserInputError:
    return UserInputError(f"{where}: the YAML nests mappings and lists more than {MAX_DEPTH} deep{_at(mark)}: refused")


def _check_depth(text: str, where: str) -> None:
    """Refuse mappings and lists nested more than MAX_DEPTH deep in the text, from the parser's
    event stream (an iterative state machine in libyaml and in PyYAML, unlike their composers),
    stopping at the first event too deep: nothing recursive runs on a deep document."""
    depth = 0
    for event in yaml.parse(text, Loader=_Loader):
        if isinstance(event, yaml.CollectionStartEvent):
            depth += 1
            if depth > MAX_DEPTH:
                raise _too_deep(where, event.start_mark)
        elif isinstance(event, yaml.CollectionEndEvent):
            depth -= 1


def _check_size(root, where: str) -> None:
    """Count the values of the composed document, each alias as many times as it is used
    (memoised per node, so the count itself is cheap); refuse above MAX_NODES, a cycle, or a
    nesting deeper than MAX_DEPTH through aliases (an anchor's depth adds to its alias's)."""
    sizes: dict[int, int] = {}
    heights: dict[int, int] = {}  # levels of mappings and lists in a node, itself included
    open_nodes: set[int] = set()

    def size(node, level: int = 1) -> int:
        key = id(node)
        if key in sizes:
            if level - 1 + heights[key] > MAX_DEPTH:
                raise _too_deep(where, node.start_mark)
            return sizes[key]
        if isinstance(node, (SequenceNode, MappingNode)) and level > MAX_DEPTH:
            raise _too_deep(where, node.start_mark)
        if key in open_nodes:
            raise UserInputError(f"{where}: an alias refers to its own anchor{_at(node.start_mark)}: "
                                 "recursive YAML is refused")
        open_nodes.add(key)
        if isinstance(node, SequenceNode):
            children = node.value
        elif isinstance(node, MappingNode):
            children = [item for pair in node.value for item in pair]
        else:
            children = []
        total, height = 1, 0
        for child in children:
            total += size(child, level + 1)
            height = max(height, heights[id(child)])
            if total > MAX_NODES:
                raise UserInputError(f"{where}: the YAML expands to more than {MAX_NODES} values (aliases "
                                     f"repeat their anchor's values){_at(node.start_mark)}: refused")
        open_nodes.discard(key)
        sizes[key] = total
        heights[key] = height + isinstance(node, (SequenceNode, MappingNode))
        return total

    size(root)


def load_yaml(text: str, where: str, tags=()) -> object:
    """Parse one plain-YAML document given by the user.

    Args:
        text: the document.
        where: what it is, for messages ("--set", "scenario file 'x.yaml'", "sweep spec s.yaml").
        tags: local tags ("!Statics") read as tagged mappings (``{"_tag": "!Statics", ...}``);
            every other tag is refused.

    Returns:
        The data (dict, list, str, int, float, bool or None).

    Raises:
        UserInputError: one line naming ``where``: too large, nested too deep, an alias bomb or a
            recursive alias, a duplicate key, a tag, or not YAML (with the line and column).
    """
    if isinstance(text, bytes):
        text = text.decode("utf-8", errors="replace")
    if len(text.encode("utf-8", errors="replace")) > MAX_BYTES:
        raise UserInputError(f"{where}: the YAML is {len(text.encode('utf-8', errors='replace'))} bytes, "
                             f"more than {MAX_BYTES}: refused")
    loader = None
    try:
        _check_depth(text, where)  # before the composer, which recurses
        loader = (_tagged_loader(frozenset(tags)) if tags else _Loader)(text)
        root = loader.get_single_node()
        if root is None:
            return None
        _check_size(root, where)
        return loader.construct_document(root)
    except _Duplicate as dup:
        raise UserInputError(f"{where}: duplicate key {short_repr(dup.key)}{_at(dup.mark)}: "
                             "give each field once") from None
    except yaml.constructor.ConstructorError as err:
        problem = " ".join(str(err.problem or err).split())
        if "could not determine a constructor for the tag" in problem:
            allowed = f" or the tags {', '.join(sorted(tags))} on a mapping" if tags else ""
            raise UserInputError(f"{where}: a YAML tag (!...) is refused{_at(err.problem_mark)}: "
                                 f"give plain YAML (mappings, lists, numbers, strings){allowed}") from None
        raise UserInputError(f"{where} is not valid YAML: {_unquoted(problem)}{_at(err.problem_mark)}") from None
    except yaml.YAMLError as err:
        problem = getattr(err, "problem", None) or getattr(err, "reason", None) or type(err).__name__
        if getattr(err, "context", None) and "single document" in err.context:
            problem = f"{err.context}, {problem}"  # "expected a single document ..., but found another"
        mark = getattr(err, "problem_mark", None)
        if isinstance(err, yaml.reader.ReaderError):  # a character YAML does not allow: its offset
            problem, mark = f"{problem} (character {err.position + 1})", None
        raise UserInputError(f"{where} is not valid YAML: {_unquoted(problem)}{_at(mark)}") from None
    except RecursionError:
        raise UserInputError(f"{where}: the YAML is nested too deeply: refused") from None
    finally:
        if loader is not None:
            loader.dispose()


def _unquoted(problem) -> str:
    """A parser's problem in words, without what it quotes of the text (PyYAML's pure-Python
    parser quotes a character, an alias or a tag handle: "found undefined alias 'x'"); token
    names such as '<block end>' stay."""
    text = re.sub(r"""\s*(['"])(?!<)(?:\\.|(?!\1).)*\1""", "", " ".join(str(problem).split()))
    return text[:200]


def load_yaml_file(path: str | Path, where: str | None = None, tags=()) -> object:
    """``load_yaml`` of a file, checked before it is read (``input_files.read_input_file``: a
    regular file of at most ``MAX_BYTES``).

    Raises:
        UserInputError: not a readable regular file, too large, or as ``load_yaml``.
    """
    path = Path(path)
    where = where or f"YAML file {quote_path(path)}"
    data = read_input_file(path, where, MAX_BYTES, "a YAML file")
    return load_yaml(data.decode("utf-8", errors="replace"), where, tags)


def yaml_kind(value) -> str:
    """What a loaded YAML value is, in words ("a string", "a list", ...), for a message that must
    not quote a file's contents (a document of the wrong shape: ``/proc/self/environ``, a key file)."""
    if value is None:
        return "an empty document (null)"
    if isinstance(value, bool):
        return "true or false"
    if isinstance(value, (int, float)):
        return "a number"
    return {str: "a string", list: "a list", dict: "a mapping"}.get(type(value), f"a {type(value).__name__}")


def dump_yaml(data) -> str:
    """Plain YAML text of data from ``load_yaml`` (no aliases: every value written out)."""

    class _NoAliases(yaml.SafeDumper):
        def ignore_aliases(self, data):
            return True

    return yaml.dump(data, Dumper=_NoAliases, default_flow_style=None, sort_keys=False)


def load_typed(data, schema, where: str, defaults=None):
    """An instance of ``schema`` (a dataclass or a pydrake config struct) from data that
    ``load_yaml`` returned (a mapping), starting from ``defaults`` (or ``schema()``), with
    pydrake's ``yaml_load_typed``. Check the data's shape first (``check_yaml_schema``):
    pydrake's messages are multi-line.

    Raises:
        UserInputError: naming ``where``, when pydrake refuses the data.
    """
    from pydrake.common.yaml import yaml_load_typed  # lazy: pydrake is 0.5 s to import

    try:
        return yaml_load_typed(schema=schema, data=dump_yaml(data if data is not None else {}), defaults=defaults)
    except (RuntimeError, ValueError, TypeError) as err:
        raise UserInputError(f"{where}: {' '.join(str(err).split())[:200]}") from None


# ------------------------------------------------------------------ schema check of loaded YAML
def schema_fields(tp) -> dict | None:
    """{field name: type} of a schema: a dataclass, or a pydrake config struct (``__fields__``,
    e.g. MultibodyPlantConfig); None for any other type."""
    if dataclasses.is_dataclass(tp):
        return typing.get_type_hints(tp)
    fields = getattr(tp, "__fields__", None) if isinstance(tp, type) else None
    if isinstance(fields, tuple) and all(hasattr(f, "name") and hasattr(f, "type") for f in fields):
        return {f.name: f.type for f in fields}
    return None


def _type_name(tp, plural: bool = False) -> str:
    origin = typing.get_origin(tp)
    if origin in (list, tuple):
        args = typing.get_args(tp)
        return "a list" + (f" of {_type_name(args[0], plural=True)}" if args else "")
    if schema_fields(tp) is not None:
        return f"{tp.__name__} mappings" if plural else f"a mapping of {tp.__name__} fields"
    names = {bool: ("true or false", "true/false values"), int: ("an integer", "integers"),
             float: ("a finite number", "finite numbers"), str: ("a string", "strings")}
    return names[tp][plural] if tp in names else str(tp)


def check_value(value, tp, path: str, where: str) -> None:
    """One YAML value against a schema type: bool, int, float (finite; an int is a float), str,
    a list of one of these, or a schema (``check_yaml_schema``). The one type check of the
    scenarios, the sweep specs and the anatomy files.

    Args:
        value: the parsed YAML value (``safe_yaml.load_yaml``).
        tp: the field's type.
        path: the field's path for messages ("insertion.speed", "grid.n_balls[0]").
        where: what the YAML came from ("--set", "scenario 'heart_left'", "sweep spec x.yaml").

    Raises:
        UserInputError: "{where}: {path} must be {type}, got {value}" (the value cut short).
    """
    if typing.get_origin(tp) is typing.Union and type(None) in typing.get_args(tp):  # Optional[T]: null or a T
        if value is None:
            return
        (tp,) = [a for a in typing.get_args(tp) if a is not type(None)]
    if tp is np.ndarray:  # a pydrake struct's vector (Rgba.rgba)
        tp = list[float]
    origin = typing.get_origin(tp)
    if tp is bool:
        ok = isinstance(value, bool)
    elif tp is int:
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif tp is float:
        # an int is a float too, but one beyond float's range (400 digits) is not a number here
        ok = ((isinstance(value, float) and math.isfinite(value))
              or (isinstance(value, int) and not isinstance(value, bool) and abs(value) <= sys.float_info.max))
    elif tp is str:
        ok = isinstance(value, str)
    elif origin in (list, tuple):
        ok = isinstance(value, list)
        args = typing.get_args(tp)
        for i, item in enumerate(value if ok and args else []):
            check_value(item, args[0], f"{path}[{i}]", where)
    elif schema_fields(tp) is not None:
        if not isinstance(value, dict):
            raise UserInputError(f"{where}: {path} must be {_type_name(tp)} "
                                 f"({', '.join(schema_fields(tp))}), got {short_repr(value)}")
        check_yaml_schema(value, tp, where, path)
        return
    else:
        raise TypeError(f"schema type {tp!r} of {path} is not checked")  # a programming error
    if not ok:
        raise UserInputError(f"{where}: {path} must be {_type_name(tp)}, got {short_repr(value)}")


def check_yaml_schema(data, schema, where: str, path: str = "") -> None:
    """Check parsed YAML against a dataclass schema: known fields, value shapes and types.

    Args:
        data: the parsed YAML (a dict).
        schema: the dataclass (ChainScenario or one of its parts, a sweep's parameters) or a
            pydrake config struct nested in it (MultibodyPlantConfig, SimulatorConfig, ...).
        where: what the YAML came from, for messages ("--set", "scenario 'heart_left'").
        path: the field path of ``data`` inside the scenario ("" at the top, "units[0]", ...).

    Raises:
        UserInputError: naming the field path, what it must be and what it got.
    """
    if not isinstance(data, dict):
        raise UserInputError(f"{where}{': ' + path if path else ''} must be {_type_name(schema)}, "
                             f"got {short_repr(data)}")
    hints = schema_fields(schema)
    for key in data:  # every key before any value: a document that is not of this schema is not quoted
        if key not in hints:
            raise UserInputError(f"{where}: unknown field {short_repr(key)}{f' in {path}' if path else ''}; "
                                 f"{schema.__name__} fields are {', '.join(hints)}")
    for key, value in data.items():
        check_value(value, hints[key], f"{path}.{key}" if path else str(key), where)
