"""Strict construction of frozen dataclasses from YAML mappings.

``build(cls, mapping, where)`` checks every key against the dataclass fields and every value
against the field's annotation; an unknown key, a wrong type or a value the class refuses is a
``UserError`` that names the full key path (``plant.effects[1].period``). Effects are resolved
through ``clm_sim.effects.EFFECTS`` by their ``type:``; nothing else maps strings to code.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import re
import reprlib
import types
import typing
from pathlib import Path

import yaml

from clm_sim.effects import EFFECTS
from clm_sim.effects.base import Effect
from clm_sim.errors import UserError
from clm_sim.records.files import RECORD_SUFFIXES


MAX_DEPTH = 64  # nesting levels: a config has fewer than ten; deeper is a generated file
MAX_NODES = 50_000  # values after alias expansion: configs have hundreds, alias bombs billions


class _StrictLoader(yaml.SafeLoader):
    """``yaml.SafeLoader`` (no Python tags, no code) that also refuses a duplicated key, which
    plain YAML resolves silently by keeping the last value, nesting deeper than ``MAX_DEPTH``
    and documents of more than ``MAX_NODES`` values once aliases are expanded."""

    _depth = 0
    _nodes = 0

    def compose_node(self, parent, index):
        self._depth += 1
        self._nodes += 1
        try:
            if self._depth > MAX_DEPTH:
                raise yaml.composer.ComposerError(
                    None, None, f"nesting deeper than {MAX_DEPTH} levels",
                    self.peek_event().start_mark)
            if self._nodes > MAX_NODES:  # refused while composing: no time spent on the rest
                raise TooLarge
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_yaml_int(self, node):
        value = super().construct_yaml_int(node)
        try:  # every number of a config is used as a float somewhere
            float(value)
        except OverflowError:
            raise yaml.constructor.ConstructorError(
                None, None, f"the integer {node.value[:12]}... ({len(node.value)} digits) is "
                f"beyond the range of a number (about 1.8e308)", node.start_mark) from None
        return value

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, (str, int, float, bool)):
                continue  # unhashable keys are refused by the base class
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


# A config is kilobytes (a reference of the 10,000 points a config may give: ~0.2 MB); its file
# size is checked before a byte is parsed, and at most 1 MiB of YAML parses in about a second.
MAX_BYTES = 2 ** 20


_StrictLoader.add_constructor("tag:yaml.org,2002:int", _StrictLoader.construct_yaml_int)


class TooLarge(Exception):
    """A document with more than ``MAX_NODES`` values, found while composing it."""


def load_yaml(path) -> dict:
    """Read a YAML mapping safely (no Python tags); one-line errors for a missing file, bad
    syntax or a duplicated key."""
    path = Path(path)
    if path.suffix.lower() in RECORD_SUFFIXES:
        raise UserError(f"{path}: a record ({path.suffix.lower()}), not a YAML file")
    try:
        if path.exists() and not path.is_dir() and not path.is_file():
            raise UserError(f"{path}: not a regular file (a device or a pipe is no config)")
        if path.is_file() and path.stat().st_size > MAX_BYTES:
            raise UserError(f"{path}: {path.stat().st_size} bytes; a config has at most "
                            f"{MAX_BYTES}")
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{path}: file not found") from None
    except (IsADirectoryError, UnicodeDecodeError) as exc:
        raise UserError(f"{path}: cannot read ({type(exc).__name__})") from None
    _prescan(text, path)
    loader = _StrictLoader(text)
    try:
        node = loader.get_single_node()
        if node is not None:
            size = _expanded_size(node, {})
            if size > MAX_NODES:
                raise UserError(f"{path}: more than {MAX_NODES} values once its aliases are "
                                f"expanded; a config is far smaller")
        data = None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        raise UserError(f"{path}: invalid YAML{where}: {getattr(exc, 'problem', exc)}") from None
    except TooLarge:
        raise UserError(f"{path}: more than {MAX_NODES} values; a config is far smaller") from None
    except RecursionError:
        raise UserError(f"{path}: invalid YAML: nested too deeply") from None
    finally:
        loader.dispose()
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a mapping of keys at the top level, "
                        f"got {type(data).__name__}")
    return data


def _prescan(text: str, path) -> None:
    """Count the document's values with libyaml's parser (C: a megabyte in a fraction of a
    second, where composing it in Python takes tens) and refuse one of more than ``MAX_NODES``
    before it is composed; syntax errors are left to the strict loader, which names them."""
    parser = getattr(yaml, "CSafeLoader", None)
    if parser is None:
        return
    counted = 0
    try:
        for event in yaml.parse(text, Loader=parser):
            if isinstance(event, (yaml.ScalarEvent, yaml.CollectionStartEvent, yaml.AliasEvent)):
                counted += 1
                if counted > MAX_NODES:
                    raise UserError(f"{path}: more than {MAX_NODES} values; a config is far "
                                    f"smaller")
    except yaml.YAMLError:
        return


def _expanded_size(node, memo: dict) -> int:
    """Values in ``node`` with every alias expanded (memoized: an alias bomb is counted, never
    built); capped just above ``MAX_NODES``."""
    key = id(node)
    if key not in memo:
        memo[key] = MAX_NODES + 1  # a node that contains itself counts as too large
        if isinstance(node, yaml.SequenceNode):
            total = 1 + sum(_expanded_size(n, memo) for n in node.value)
        elif isinstance(node, yaml.MappingNode):
            total = 1 + sum(_expanded_size(k, memo) + _expanded_size(v, memo)
                            for k, v in node.value)
        else:
            total = 1
        memo[key] = min(total, MAX_NODES + 1)
    return memo[key]


_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = _SHORT.maxset = 4
_SHORT.maxlevel = 2


def show(value) -> str:
    """A value in an error message: its type and a short excerpt, never the whole value."""
    if value is None or isinstance(value, bool):
        return repr(value)
    return f"{type(value).__name__} {_SHORT.repr(value)}"


def _type_name(tp) -> str:
    return getattr(tp, "__name__", str(tp)).replace("typing.", "")


# A number PyYAML (YAML 1.1) reads as text: an exponent without a dot in the mantissa or without
# a sign (1e-4, 1.0e4); Python's float() reads it.
_YAML_TEXT_NUMBER = re.compile(r"([-+]?)(\d*)\.?(\d*)[eE]([-+]?)(\d+)")


def _yaml_text_hint(value) -> str:
    """For text such as ``1e-4`` that YAML read as a string: how to write it as a number."""
    match = _YAML_TEXT_NUMBER.fullmatch(value.strip()) if isinstance(value, str) else None
    if match is None or not (match[2] or match[3]):
        return ""
    sign, whole, frac, exp_sign, exp = match.groups()
    return (f" (YAML 1.1 reads {value.strip()} as text: write {sign}{whole or '0'}."
            f"{frac or '0'}e{exp_sign or '+'}{exp}, with a dot and a signed exponent)")


def _convert(tp, value, key: str):
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is typing.Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = {}
        for arg in (a for a in args if a is not type(None)):
            try:
                return _convert(arg, value, key)
            except UserError as exc:
                errors[arg] = str(exc)
        if len(errors) == 1:
            raise UserError(next(iter(errors.values())))
        raise UserError(_form_error(errors, value, key) or
                        f"{key}: expected {' or '.join(_type_name(a) for a in args)}, "
                        f"got {show(value)}")
    if origin is typing.Literal:
        if value not in args:
            raise UserError(f"{key}: expected one of {', '.join(map(repr, args))}, got {show(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise UserError(f"{key}: expected a number, got {show(value)}{_yaml_text_hint(value)}")
        if not math.isfinite(value):
            raise UserError(f"{key}: expected a finite number, got {show(value)}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise UserError(f"{key}: expected an integer, got {show(value)}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise UserError(f"{key}: expected true or false, got {show(value)}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise UserError(f"{key}: expected a string, got {show(value)}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise UserError(f"{key}: expected a list, got {show(value)}")
        item = args[0]
        return tuple(_convert(item, v, f"{key}[{i}]") for i, v in enumerate(value))
    if origin is dict:
        if not isinstance(value, dict):
            raise UserError(f"{key}: expected a mapping, got {show(value)}")
        kt, vt = args
        return {_convert(kt, k, f"{key}"): _convert(vt, v, f"{key}.{k}") for k, v in value.items()}
    if isinstance(tp, type) and issubclass(tp, Effect):
        return build_effect(value, key)
    if dataclasses.is_dataclass(tp):
        return build(tp, value, key)
    raise TypeError(f"schema: unsupported annotation {tp!r} at {key}")


def _form_error(errors: dict, value, key: str) -> str | None:
    """Of a mapping that none of several dataclass forms takes (``errors``: form -> its error),
    the error of the one form whose keys it uses most, or, where two forms' keys are mixed, a
    line naming the keys of each; None where its keys tell no form."""
    if not isinstance(value, dict):
        return None
    used = {}
    for form in errors:
        if dataclasses.is_dataclass(form):
            keys = {f.name for f in dataclasses.fields(form) if f.init}
            used[form] = [k for k in value if k in keys | set(getattr(form, "aliases", {}))]
    most = max((len(k) for k in used.values()), default=0)
    if not most:
        return None
    best = [form for form, keys in used.items() if len(keys) == most]
    if len(best) == 1:
        return errors[best[0]]
    if len({tuple(used[form]) for form in best}) == 1:  # keys every form takes: no telling
        return None
    return (f"{key}: keys of different forms mixed: "
            + " and ".join(f"{', '.join(used[f])} ({_type_name(f)})" for f in best)
            + "; give the keys of one")


@functools.lru_cache(maxsize=None)
def _type_hints(cls) -> dict:
    # Resolving string annotations compiles them each time; sweeps build thousands of configs.
    return typing.get_type_hints(cls)


def build(cls, mapping, key: str, *, aliases: dict[str, str] | None = None):
    """An instance of dataclass ``cls`` from ``mapping``; errors name ``key`` and the field."""
    if mapping is None:
        mapping = {}
    if not isinstance(mapping, dict):
        raise UserError(f"{key}: expected a mapping, got {show(mapping)}")
    aliases = dict(aliases or {}, **getattr(cls, "aliases", {}))
    hints = _type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs = {}
    for name, value in mapping.items():
        attr = aliases.get(name, name)
        if not isinstance(name, str) or attr not in fields:
            known = ", ".join(sorted(set(fields) - set(aliases.values()) | set(aliases)))
            raise UserError(f"{key}.{name}: unknown key; known keys: {known}")
        kwargs[attr] = _convert(hints[attr], value, f"{key}.{name}")
    config_name = {attr: name for name, attr in aliases.items()}  # named as the file names it
    missing = [config_name.get(name, name) for name, f in fields.items() if name not in kwargs
               and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    if missing:
        raise UserError(f"{key}.{missing[0]}: missing; {_type_name(cls)} needs "
                        f"{', '.join(missing)}")
    try:
        return cls(**kwargs)
    except UserError as exc:
        # The class names itself ("plant: mass must be > 0"); keep the full key path only once.
        head, _, rest = str(exc).partition(": ")
        message = rest if rest and key.rsplit(".", 1)[-1] == head else str(exc)
        raise UserError(f"{key}: {message}") from None
    except TypeError as exc:  # a required InitVar (not a field, so not in the check above)
        raise UserError(f"{key}: {exc}") from None


def build_effect(mapping, key: str) -> Effect:
    """An effect from ``{type: NAME, **parameters}`` through the ``EFFECTS`` registry."""
    if not isinstance(mapping, dict) or "type" not in mapping:
        raise UserError(f"{key}: an effect needs a 'type:' (one of {', '.join(EFFECTS)})")
    name = mapping["type"]
    if not isinstance(name, str) or name not in EFFECTS:
        raise UserError(f"{key}.type: unknown effect {name!r}; known: {', '.join(EFFECTS)}")
    return build(EFFECTS[name], {k: v for k, v in mapping.items() if k != "type"}, key)


def to_plain(obj):
    """A dataclass (or nested structure of them) as plain YAML-able data, effects with ``type``."""
    if isinstance(obj, Effect):
        return obj.as_config()
    if dataclasses.is_dataclass(obj):
        out = {}
        rename = {v: k for k, v in getattr(type(obj), "aliases", {}).items()}
        for f in dataclasses.fields(obj):
            out[rename.get(f.name, f.name)] = to_plain(getattr(obj, f.name))
        return out
    if isinstance(obj, (list, tuple)):
        return [to_plain(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_plain(v) for k, v in obj.items()}
    return obj
