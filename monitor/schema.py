"""Building blocks of the one configuration schema (monitor.toml).

Every section of the config is a frozen pydantic dataclass declared with ``@section("name")``:
unknown keys are refused (``extra="forbid"``), each field's type and bounds are in its
annotation (the aliases below), cross-field rules are ``model_validator``s. The same rules run
when a section is built in code (``PolicyConfig(clear_time=0)``) and when the whole file is
loaded (``monitor.config.load_config``), so there is one place to read what a setting accepts.

TOML has real types, so the scalars are strict: ``"1"`` or ``true`` where seconds are expected
is a mistake, not something to coerce (integers still pass as floats, arrays as tuples).
Path fields (``ConfigPath``) resolve against the config file's folder when the file is loaded
(validation context ``{"base": folder}``): a service started by systemd has another working
directory than the person who tested it.

Errors become one ``ConfigError`` line naming the section and key (and the file, when loading).
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

from pydantic import AfterValidator, ConfigDict, Field, Strict, ValidationError, ValidationInfo
from pydantic.dataclasses import dataclass as pydantic_dataclass

from monitor.errors import ConfigError

Float = Annotated[float, Strict(), Field(allow_inf_nan=False)]  # finite
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
Text = Annotated[str, Strict()]
Seconds = Annotated[Float, Field(gt=0)]  # a positive, finite number of seconds
NonNegative = Annotated[Float, Field(ge=0)]
Fraction = Annotated[Float, Field(ge=0, le=1)]  # 0..1


def _resolve(value: str | None, info: ValidationInfo) -> str | None:
    base = (info.context or {}).get("base")
    if value and base is not None and not Path(value).is_absolute():
        return str(Path(base) / value)
    return value


# a file named in the config: relative to the config file's folder when loaded from a file
ConfigPath = Annotated[Text | None, AfterValidator(_resolve)]



def config_files(section: Any, prefix: str = "") -> dict[str, str]:
    """Every file a config section (and the sections in it) names in a ``ConfigPath`` field,
    as ``{"section.key": path}`` (a tuple of sections as ``section[<id>].key``, a mapping of
    paths as ``section.key.<name>``): what the commissioned fingerprint digests, found from the
    annotations so that a path setting added later is covered without a list to keep."""
    out: dict[str, str] = {}
    hints = typing.get_type_hints(type(section), include_extras=True)
    for f in dataclasses.fields(section):
        value, hint = getattr(section, f.name), hints.get(f.name)
        name = f"{prefix}{f.name}"
        if hint == ConfigPath:
            if value:
                out[name] = str(value)
        elif isinstance(value, dict) and typing.get_args(hint)[-1:] == (ConfigPath,):
            out.update({f"{name}.{k}": str(v) for k, v in sorted(value.items()) if v})
        elif dataclasses.is_dataclass(value):
            out.update(config_files(value, f"{name}."))
        elif isinstance(value, tuple) and value and all(map(dataclasses.is_dataclass, value)):
            for k, item in enumerate(value):  # [[camera]] entries: camera[<id>].key
                title = f"{prefix}{getattr(item, '__section__', f.name)}"
                out.update(config_files(item, f"{title}[{getattr(item, 'id', k)}]."))
    return out


# fields whose values are never printed in an error (only their type)
SECRET_KEYS = frozenset({"password"})

_SECTION = ConfigDict(extra="forbid")

T = TypeVar("T")

# the keys each section accepts, by section name, filled in by ``@section`` as each stage's
# module declares its section: an error names the known keys without this bottom layer
# importing monitor.config (which assembles the sections, and so sits above every stage)
_KEYS: dict[str, Callable[[], list[str]]] = {}


def section(name: str, keys: tuple[str, ...] | None = None) -> Callable[[type[T]], type[T]]:
    """Make ``cls`` a frozen, validated config section named ``name`` in messages. ``keys``:
    the keys an error lists as known (the dataclass fields when not given)."""

    def wrap(cls: type[T]) -> type[T]:
        cls = pydantic_dataclass(frozen=True, config=_SECTION)(cls)
        init = cls.__init__

        @functools.wraps(init)
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            try:
                init(self, *args, **kwargs)
            except ValidationError as exc:  # built in code: one line naming section and key
                raise ConfigError(describe(exc, name)) from None

        cls.__init__ = __init__  # type: ignore[method-assign]
        cls.__section__ = name  # type: ignore[attr-defined]
        _KEYS[name] = ((lambda: list(keys)) if keys is not None
                       else (lambda: sorted(f.name for f in dataclasses.fields(cls))))
        return cls

    return wrap


def describe(exc: ValidationError, section_name: str, where: str | None = None,
             sections: Callable[[tuple], tuple[str, tuple]] | None = None) -> str:
    """The first error of ``exc`` as one line. ``where`` (a file name) switches to the file
    style ``file: [section] key: message (got a float)``, which never prints the value (it
    may be a password); in code the value is shown. ``sections`` maps a location in the
    whole config to (section name, location inside that section)."""
    err = exc.errors(include_url=False)[0]
    loc = tuple(err["loc"])
    name = section_name
    if sections is not None:
        name, loc = sections(loc)
    key = ".".join(str(p) for p in loc)
    kind, value = err["type"], err.get("input")
    if kind == "unexpected_keyword_argument":
        return _unknown(name, key, where)
    msg = err["msg"]
    if kind == "value_error":  # our own rules: their message names the keys it is about
        msg = msg.removeprefix("Value error, ")
        if key:
            msg = f"{key}: {msg}"
        return f"{where}: [{name}] {msg}" if where else f"{name}.{msg}"
    msg = msg.replace("Input should be", "should be").replace("a valid tuple", "an array")
    # a wrong type shows the type only (the value may be a password in the wrong place); a
    # value out of bounds or not among the choices shows the value, unless it is a secret
    secret = kind.endswith("_type") or (bool(loc) and loc[-1] in SECRET_KEYS)
    shown = toml_type(value) if secret else repr(value)
    if where:
        at = f"[{name}] {key}" if key else f"[{name}]"
        return f"{where}: {at}: {msg} (got {shown})"
    return f"{name}.{key}: {msg} (got {shown})" if key else f"{name}: {msg} (got {shown})"


def section_keys(name: str) -> list[str]:
    """The keys a section accepts (the sections themselves for the whole config)."""
    return _KEYS.get(name, _KEYS.get("config", list))()


def _unknown(name: str, key: str, where: str | None) -> str:
    known = ", ".join(section_keys(name))
    if where:
        return f"{where}: [{name}] unknown key {key!r} (known: {known})"
    return f"{name}: unknown key {key!r} (known: {known})"


def toml_type(value: Any) -> str:
    """The TOML name of a value's type (never the value: it may be a password)."""
    for kind, label in ((bool, "a boolean"), (int, "an integer"), (float, "a float"),
                        (str, "a string"), (list | tuple, "an array"), (dict, "a table")):
        if isinstance(value, kind):
            return label
    return type(value).__name__
