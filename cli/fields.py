"""Typer options generated from an options model's fields: each option's type, default and help
come from the field (its annotation, its default, its attribute docstring), so the model is the
one source of all three; a command only lists which fields it exposes and their flags
(docs/cli.md)."""

from __future__ import annotations

import functools
import inspect
import re
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, TypeVar

import typer

from qsls.pipeline.core.config import merge

F = TypeVar("F", bound=Callable[..., Any])


@dataclass(frozen=True)
class Flag:
    """How the command line spells one field: its flags (``"--robust/--no-robust"`` for an
    on/off pair) and, where the field's annotation does not say
    it, how the command line's text becomes the model's value (``parse(text, flag)``) and the
    text's type (``kind``)."""

    flags: tuple[str, ...]
    parse: Callable[[Any, str], Any] | None = None
    kind: Any = None
    name: str | None = None
    """The command's parameter (default: the field's last part), where that is taken."""


def auto_or_number(text: str, flag: str) -> float | str:
    """A ``Flag`` parser for a field that is ``auto`` or a number (``--time-offset``,
    ``--min-separation``): anything else is a one-line error naming the flag."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return float(text)
    except ValueError:
        from qsls.pipeline.core.errors import ConfigError

        raise ConfigError(f"{flag}: expected 'auto' or a number, got {text!r}") from None


def repeated_list(texts: list[str], flag: str) -> list[str]:
    """A ``Flag`` parser for a list option given repeated and/or comma-separated
    (``--recorded a --recorded b,c`` -> ``[a, b, c]``); use with ``kind=list[str]``."""
    return [p.strip() for text in texts for p in text.split(",") if p.strip()]


def as_given(text: str, flag: str) -> str:
    """A ``Flag`` parser that hands the model the command line's text (a number-or-name the
    stage reads itself, a reference spelled as text)."""
    return text


Table = Mapping[str, "Flag | tuple[str, ...]"]
"""A command's exposed fields (dotted for a nested model: ``sim.controller.backend``) and how
it spells them."""


def _flag(spec: Flag | tuple[str, ...]) -> Flag:
    return spec if isinstance(spec, Flag) else Flag(tuple(spec))


def field_info(model: Any, dotted: str) -> tuple[Any, str]:
    """(the model holding the field ``dotted`` names, the field's own name)."""
    *outer, last = dotted.split(".")
    for part in outer:
        model = model.model_fields[part].annotation
    if last not in model.model_fields:
        raise KeyError(f"{model.__name__} has no field '{last}'")
    return model, last


def _members(annotation: Any) -> list[Any]:
    """The members of a union annotation other than ``None`` (``Annotated`` unwrapped)."""
    if typing.get_origin(annotation) is typing.Annotated:
        annotation = typing.get_args(annotation)[0]
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return [m for a in typing.get_args(annotation) if a is not type(None) for m in _members(a)]
    return [annotation]


def _is_text(a: Any) -> bool:
    return a is str or typing.get_origin(a) is Literal


def _items(a: Any) -> str:
    """``parse_list``'s kind for a list or tuple annotation's items."""
    item = (typing.get_args(a) or (float,))[0]
    if typing.get_origin(item) in (list, tuple) or item is float:
        return "float"  # a matrix is given by its diagonal
    return "int" if item is int else "value"


def _reader(annotation: Any) -> tuple[Any, Callable[[Any, str], Any]]:
    """The command line's type for a field's annotation, and its parser (text -> value): a
    number, a name, a flag as given; ``0.1``/``p95`` for a number-or-name; a comma-separated
    list for a list, a tuple or a (diagonal) matrix."""
    from qsls.cli.common import number_or_name, parse_list

    members = _members(annotation)
    if len(members) == 1 and members[0] in (bool, int, float, Path):
        return members[0], lambda v, flag: v
    if all(_is_text(a) for a in members):
        return str, lambda v, flag: v
    seq = [a for a in members if typing.get_origin(a) in (list, tuple)]
    if len(seq) == 1 and len(members) == 1:
        kind = _items(seq[0])
        return str, lambda v, flag: parse_list(v, flag, kind)
    if not seq:  # a number or a name (S = 0.1 or p95; m = 3 or auto)
        return str, lambda v, flag: number_or_name(v)
    raise TypeError(f"no command-line reading of {annotation}; give the Flag a parse")


def field_help(model: Any, dotted: str, flags: tuple[str, ...] = ()) -> str:
    """A field's help line: its attribute docstring, then its default as the command line
    writes it, ``(default: 0.5)``. A field whose default is ``None`` says in its docstring what
    that means (``default: the error model's radius``)."""
    owner, name = field_info(model, dotted)
    info = owner.model_fields[name]
    text = doc_text(info.description or "")
    default = info.get_default(call_default_factory=True)
    if default is None:
        return text if "default" in text.lower() else f"{text} (default: none)"
    pair = next((tuple(f.split("/", 1)) for f in flags if "/" in f), None)
    return f"{text} (default: {default_text(owner, name, pair)})"  # type: ignore[arg-type]


def doc_text(doc: str) -> str:
    """An attribute docstring as one line of help: roles and literal quotes dropped."""
    doc = re.sub(r":\w+:`~?([^`]+)`", r"\1", doc)
    return " ".join(doc.replace("``", "").split())


def default_text(model: Any, field: str, flags: tuple[str, str] | None = None) -> str:
    """A model field's default as the command line writes it: ``0.5``, ``l1``, ``max``,
    ``10,10,10,1,1,1`` for a diagonal matrix, ``none``; for an on/off pair of ``flags``,
    the flag that is the default."""
    info = model.model_fields[field]
    value = info.get_default(call_default_factory=True)
    if hasattr(value, "model_dump"):
        value = value.model_dump()
    if isinstance(value, bool):
        if flags is not None:
            return flags[0] if value else flags[1]
        return "on" if value else "off"
    if value is None:
        return "none"
    if isinstance(value, list | tuple) and value and isinstance(value[0], list | tuple):
        import numpy as np

        m = np.asarray(value, dtype=float)
        if m.ndim == 2 and m.shape[0] == m.shape[1] and np.allclose(m, np.diag(np.diag(m))):
            value = list(np.diag(m))
    if isinstance(value, dict):  # a sweep grid
        return "; ".join(f"{k}={','.join(_plain(v) for v in vs)}" for k, vs in value.items())
    if isinstance(value, list | tuple):
        return ",".join(_plain(v) for v in value)
    return _plain(value)


def _plain(v: Any) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _param(name: str, flag: Flag, model: Any, dotted: str) -> tuple[inspect.Parameter, Any]:
    owner, field = field_info(model, dotted)
    if flag.parse is not None:
        kind, parse = flag.kind or str, flag.parse
    else:
        kind, parse = _reader(owner.model_fields[field].annotation)
    option = typer.Option(None, *flag.flags, help=field_help(model, dotted, flag.flags))
    annotation = kind | None
    param = inspect.Parameter(name, inspect.Parameter.KEYWORD_ONLY, default=option,
                              annotation=annotation)  # fmt: skip
    return param, parse


def config_only_text(fields: Mapping[str, str], width: int = 76) -> str:
    """The ``--help`` epilog's paragraph on the config-only options (``""`` for none)."""
    import textwrap

    if not fields:
        return ""
    body = "; ".join(f"{k} ({v})" for k, v in fields.items())
    lines = textwrap.wrap(f"Config file only (--config): {body}.", width - 2)
    return "\b\n" + "\n".join(f"  {ln}" if i else ln for i, ln in enumerate(lines))


def _nested(dotted: str, value: Any) -> tuple[str, Any]:
    """``("sim.controller.backend", "c")`` -> ``("sim", {"controller": {"backend": "c"}})``."""
    top, *rest = dotted.split(".")
    for part in reversed(rest):
        value = {part: value}
    return top, value


CONFIG_ONLY = "__qsls_config_only__"
"""The attribute of a generated command naming its model's config-only fields (``--help``
lists them, :func:`qsls.cli.main._register`)."""


def model_options(
    model: Any, table: Table, config_only: Mapping[str, str] | None = None
) -> Callable[[F], F]:
    """Give a command the options of ``model``'s fields in ``table``: Typer sees one option per
    field (named after the field's last part), ``None`` unless the user sets it, so the
    model's default (or the config file's value) applies. The command takes ``given``, the
    options set on the command line as the model's values (``{"T": 10, "sim": {...}}``).

    ``config_only``: the model's fields the command line does not take, each with where it
    is set instead (``{"sim": "the config's simulate: section"}``); ``--help`` lists them.
    Every field of the model is in ``table``, in ``config_only``, or set by the command's
    own parameters (tests/test_cli_help.py checks it: an option qsls's messages name must
    not be refused as unknown)."""
    specs = {d: _flag(f) for d, f in table.items()}

    def wrap(fn: F) -> F:
        sig = inspect.signature(fn)
        own = [p for p in sig.parameters.values() if p.name != "given"]
        built = {}
        for dotted, flag in specs.items():
            name = flag.name or dotted.rsplit(".", 1)[-1]
            built[name] = (dotted, *_param(name, flag, model, dotted))

        @functools.wraps(fn)
        def command(*args: Any, **kwargs: Any) -> Any:
            given: dict[str, Any] = {}
            for name, (dotted, _, parse) in built.items():
                value = kwargs.pop(name)
                if value is not None:
                    flag = next(f for f in specs[dotted].flags if f.startswith("--"))
                    given = merge(given, dict([_nested(dotted, parse(value, flag.split("/")[0]))]))
            return fn(*args, given=given, **kwargs)

        params = own + [p for _, p, _ in built.values()]
        command.__signature__ = sig.replace(parameters=params)  # type: ignore[attr-defined]
        setattr(command, CONFIG_ONLY, dict(config_only or {}))
        command.__annotations__ = {
            **{k: v for k, v in fn.__annotations__.items() if k != "given"},
            **{p.name: p.annotation for _, p, _ in built.values()},
        }
        return command  # type: ignore[return-value]

    return wrap
