"""Configuration: pydantic models for every stage's options, loaded from YAML.

Each stage module defines its options as a subclass of :class:`Options` (frozen, unknown
keys rejected). :func:`load_options` reads an optional YAML file, lays the command line's
values over it (the command line wins) and validates, turning pydantic's errors into one
readable :class:`ConfigError` that suggests the nearest valid name for a misspelled key.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    ValidationError,
    field_validator,
)

from qsls.pipeline.core.errors import ConfigError

T = TypeVar("T", bound="Options")


class Options(BaseModel):
    """Base of every options model: immutable, unknown keys are errors, and every number
    is finite (``nan`` and ``inf`` are refused wherever they appear: a plain number, a
    number-or-name such as ``S``, a list or a matrix)."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, validate_default=True, use_attribute_docstrings=True
    )

    @field_validator("*", mode="before")
    @classmethod
    def _finite(cls, value: Any) -> Any:
        if _nonfinite(value):
            raise ValueError("must be a finite number")
        return value


def _at_most(limit: float, why: str) -> Any:
    """A pydantic check refusing a value above ``limit``, the message saying ``why``."""

    def check(value: Any) -> Any:
        if value > limit:
            raise ValueError(f"at most {limit if isinstance(limit, int) else f'{limit:g}'} ({why})")
        return value

    return AfterValidator(check)


MAX_SEED = 2**32 - 1
"""The largest seed: numpy's legacy generators stop at ``2^32 - 1``, and seeds are stored in
int64 columns offset by the flight count (``seed + k``), which stays inside 64 bits from here;
a larger one failed only after flying (pyarrow's OverflowError) or in a worker."""
Seed = Annotated[
    int, Field(ge=0), _at_most(MAX_SEED, "a seed is 0 .. 2^32 - 1: seeds are stored in 64 bits")
]
"""A random seed, ``0 .. 2^32 - 1`` (:data:`MAX_SEED`), checked when the options are read,
before anything flies."""
MAX_FLIGHTS = 10_000
"""The most flights one count may ask for (calibration, range, validation flights; fly's
seeds): a flight is seconds of CPU and megabytes of tables, so 10 000 is hours of flying and
gigabytes (a certificate needs 19, docs/calibration.md); a count of 10^9 ran out of memory
before the first flight instead of being refused."""
FlightCount = Annotated[
    int,
    Field(ge=0),
    _at_most(MAX_FLIGHTS, "10 000 flights are hours of flying; a certificate needs 19"),
]
"""A number of flights, ``0 .. MAX_FLIGHTS``."""
MAX_DURATION_S = 86_400.0
"""The longest flight (s): a day, longer than any battery (a simulated day takes hours and
about 140 MB); a longer one ran out of memory instead of being refused."""
Duration = Annotated[
    float, Field(gt=0), _at_most(MAX_DURATION_S, "seconds: a day, longer than any battery")
]
"""A flight's duration in seconds, ``(0, MAX_DURATION_S]``."""


def _nonfinite(value: Any) -> bool:
    """Whether ``value`` (a number, or nested lists/tuples of them) holds a nan or an inf."""
    import math

    if isinstance(value, float):
        return not math.isfinite(value)
    return isinstance(value, list | tuple) and any(_nonfinite(v) for v in value)


def read_yaml(path: Path) -> dict[str, Any]:
    """A YAML file's top-level mapping; a clear error for a missing or malformed file."""
    import yaml

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: config file not found")
    raw = path.read_bytes()
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{path}: {len(raw)} bytes, more than a config may hold ({MAX_CONFIG_BYTES}); "
            "pass the YAML config, not a data file"
        )
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}); "
            "save the config as UTF-8 and try again"
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}: not valid YAML{where}: {problem}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of option names to values at the top level")
    if expanded_size(data, MAX_CONFIG_VALUES) > MAX_CONFIG_VALUES:
        raise ConfigError(
            f"{path}: expands to more than {MAX_CONFIG_VALUES} values (YAML aliases that "
            "repeat each other, or refer to themselves); write the values out"
        )
    return data


MAX_CONFIG_BYTES = 4 << 20
"""A config file's size limit (configs are a few kB)."""
MAX_CONFIG_VALUES = 200_000
"""How many values a config may expand to once its YAML aliases are followed (a 1 kB alias
"bomb" expands to billions; every stage walks the options, so it would never return)."""


def expanded_size(obj: Any, cap: int) -> int:
    """How many values ``obj`` holds with shared (aliased) parts counted each time they
    occur, counting no further than just past ``cap``."""
    n, stack = 0, [obj]
    while stack and n <= cap:
        item = stack.pop()
        n += 1
        if isinstance(item, Mapping):
            stack.extend(item.values())
        elif isinstance(item, list | tuple):
            stack.extend(item)
    return n


def merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Recursive dict merge; values in ``over`` win, ``None`` in ``over`` means 'not given'."""
    out = dict(base)
    for key, value in over.items():
        if value is None:
            continue
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def load_options(
    model: type[T],
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
    *,
    section: str | None = None,
) -> T:
    """Validate ``model`` from a YAML file (optionally one ``section`` of it) and overrides."""
    data = read_section(config, section)
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    data = merge(data, given)
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        # blame the command line for what it gave, the file for the rest
        tops = {str(e["loc"][0]) for e in exc.errors() if e.get("loc")}
        cli = tops & set(given)
        if config is None or (cli and cli == tops):
            source = "command line" if cli else "options"
        else:
            source = str(config)
        raise ConfigError(f"{source}: {describe_validation_error(model, exc)}") from None


# The --config files this process read: inputs of the stage like any other, so an output
# that is, contains or lies inside one is refused (qsls.pipeline.core.artifacts.refuse_overlap).
_CONFIG_FILES: list[Path] = []


def config_files() -> tuple[Path, ...]:
    """The ``--config`` files read so far by this command (:func:`read_section`)."""
    return tuple(_CONFIG_FILES)


def forget_config_files() -> None:
    """Start a new command (the CLI calls this; one process may run several in tests)."""
    _CONFIG_FILES.clear()


SECTION_NAMES = frozenset({"simulate", "ingest", "fit", "sweep", "synth", "calibrate",
                           "evaluate", "fly", "export", "replay", "problem", "report"})  # fmt: skip
"""The sections of a run config (a misspelled one is named with the one meant)."""

SHARED = "problem"
"""A run config's section of the synthesis problem's settings that ``sweep:`` and ``synth:``
share (``R``, ``measure``, ``beta``, ``gate``, ``error_scale``, ``H``, ``plant``, ...: the fields
of :class:`qsls.pipeline.control.options.ProblemOptions`), laid under both so a config states
them once; each section's own keys win (docs/run.md#the-config)."""
SHARED_UNDER = ("sweep", "synth")
"""The sections the ``problem:`` section is laid under."""


def with_shared(data: Mapping[str, Any], source: str | Path = "config") -> dict[str, Any]:
    """``data`` (a whole config file) with its ``problem:`` section laid under its ``sweep:``
    and ``synth:`` sections, those it has (merged: the section's keys win), and removed."""
    out = dict(data)
    shared = out.pop(SHARED, None)
    if shared is None:
        return out
    if not isinstance(shared, Mapping):
        raise ConfigError(f"{source}: section '{SHARED}' must be a mapping")
    for key in SHARED_UNDER:
        if key in out:
            sub = out[key]
            if sub is not None and not isinstance(sub, Mapping):
                raise ConfigError(f"{source}: section '{key}' must be a mapping")
            out[key] = merge(shared, sub or {})
    return out


def read_section(config: Path | None, section: str | None) -> dict[str, Any]:
    """A command's options in a YAML file, the same way for every command: the file's
    ``section`` mapping when it has one (a ``qsls run`` config holds every stage's), else
    the whole file; ``sweep`` and ``synth`` with the file's ``problem:`` laid under them
    (:func:`with_shared`). No file: no options."""
    if config is None:
        return {}
    data = read_yaml(config)
    _CONFIG_FILES.append(Path(config))
    if section in SHARED_UNDER and SHARED in data:
        data = with_shared({**data, section: data.get(section) or {}}, config)
    if section is not None and section not in data:
        near = difflib.get_close_matches(section, [str(k) for k in data], n=1, cutoff=0.6)
        if near and isinstance(data[near[0]], Mapping) and near[0] not in SECTION_NAMES:
            raise ConfigError(f"{config}: section '{near[0]}': did you mean '{section}'?")
    if section is None or section not in data:
        return data
    sub = data[section]
    if sub is None:
        return {}
    if not isinstance(sub, dict):
        raise ConfigError(f"{config}: section '{section}' must be a mapping")
    return dict(sub)


def validate(model: type[T], data: Mapping[str, Any], source: str = "options") -> T:
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{source}: {describe_validation_error(model, exc)}") from None


def layered(
    model: type[T], base: Mapping[str, Any], *over: Mapping[str, Any], source: str = "options"
) -> T:
    """``model`` validated from ``base`` (as written) with each mapping of ``over`` laid over
    it in turn (:func:`merge`: its keys win, nested mappings merge, ``None`` is 'not given');
    errors name ``source``. A run's flight over the run's section, its ``calibrate:`` over
    the run's ``simulate:`` (docs/run.md#sections)."""
    data = dict(base)
    for layer in over:
        data = merge(data, layer)
    return validate(model, data, source)


_TYPE_TAGS = frozenset({"int", "float", "str", "bool", "list", "tuple", "dict", "none"})


def _plain_loc(loc: tuple[Any, ...]) -> tuple[Any, ...]:
    """``loc`` without pydantic's union-member tags (``('m', 'int')`` -> ``('m',)``)."""
    return loc[:1] + tuple(
        p for p in loc[1:] if not (isinstance(p, str) and ("[" in p or p in _TYPE_TAGS))
    )


def describe_validation_error(model: type[BaseModel], exc: ValidationError) -> str:
    """One line per problem (per option: a union's members are not listed), joined by '; ',
    with suggestions for unknown keys."""
    parts = []
    seen: set[tuple[Any, ...]] = set()
    for err in exc.errors():
        loc = _plain_loc(tuple(err.get("loc", ())))
        if loc in seen and err.get("type") != "extra_forbidden":
            continue  # one line per option (a union reports each member)
        seen.add(loc)
        dotted = ".".join(str(p) for p in loc) or "(top level)"
        if err.get("type") == "extra_forbidden":
            valid = _field_names(model, loc[:-1])
            near = difflib.get_close_matches(str(loc[-1]), valid, n=1, cutoff=0.5)
            hint = f"; did you mean '{near[0]}'?" if near else f"; valid: {', '.join(valid)}"
            parts.append(f"unknown option '{dotted}'{hint}")
        elif err.get("type") == "missing":
            parts.append(f"missing required option '{dotted}'")
        else:
            msg = err.get("msg", "invalid value").removeprefix("Value error, ")
            got = err.get("input")
            shown = f" (got {_short(got)})" if got is not None and not isinstance(got, dict) else ""
            parts.append(f"'{dotted}': {msg}{shown}")
    return "; ".join(parts)


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to about ``limit`` characters (a 20 000-item list given)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 5]}...{text[-1]}"


def _field_names(model: type[BaseModel], loc: tuple[Any, ...]) -> list[str]:
    """Field names of the (nested) model found by following ``loc`` from ``model``."""
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        fields = getattr(current, "model_fields", None)
        if not fields or part not in fields:
            return []
        current = _model_of(fields[part].annotation)
    fields = getattr(current, "model_fields", None) or {}
    return sorted(fields)


def _model_of(annotation: Any) -> Any:
    """The BaseModel inside an annotation like ``Model | None`` or ``list[Model]``."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()) or ():
        found = _model_of(arg)
        if found is not None:
            return found
    return None
