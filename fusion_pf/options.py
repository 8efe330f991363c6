"""One source of truth for options: config fields that also make the command line.

A stage's configuration is a frozen dataclass whose fields are declared with
:func:`option`. The field carries its default, help text, unit, valid range or
choices and, where the command line needs one, a parser from text. From that
single declaration:

* :func:`validate` checks an instance (called from ``__post_init__``), so a
  config built from Python, from the command line or from a stored JSON is
  checked the same way, before any device or file is opened;
* :func:`add_options` registers one ``--flag`` per field on an
  :mod:`argparse` parser, with the unit and the *real* default in ``--help``;
* :func:`from_args` builds the config from parsed arguments: only the flags
  the user gave are passed, every other field keeps its dataclass default.

Errors are :class:`~fusion_pf.errors.InputError` naming the option (and its
flag), the bad value and the valid range.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import InputError

__all__ = ["Spec", "add_options", "from_args", "option", "option_help", "parse_pairs", "parse_tuple", "validate"]


@dataclass(frozen=True)
class Spec:
    """What a config field means: the metadata :func:`option` attaches to a dataclass field.

    Parameters
    ----------
    help : str
        One sentence for ``--help``.
    unit : str or None
        Unit shown after the help (``"px"``, ``"mm"``, ``"px/frame"``).
    lo, hi : float or None
        Inclusive valid range of a number (each bound optional).
    choices : tuple or None
        Valid values of a choice.
    kind : {"int", "float", "str", "bool", "any"}
        How a scalar is checked; ``"any"`` leaves the checking to ``check``.
    parse : callable or None
        Command line text -> value (default: by ``kind``).
    show : callable or None
        Value -> text for ``--help`` (default: ``str``).
    check : callable or None
        ``(label, value) -> value``: extra validation / normalisation.
    flag : str or None
        Command line flag (default ``--field-name``); None with ``cli=False``.
    metavar : str or None
    cli : bool
        Whether the field has a command line flag.
    optional : bool
        None is a valid value (it means what the help says).
    const : object or None
        Value of the bare flag: when set, the flag's argument may be left out.
    """

    help: str
    unit: str | None = None
    lo: float | None = None
    hi: float | None = None
    choices: tuple | None = None
    kind: str = "any"
    parse: Callable[[str], Any] | None = None
    show: Callable[[Any], str] | None = None
    check: Callable[[str, Any], Any] | None = None
    flag: str | None = None
    metavar: str | None = None
    cli: bool = True
    optional: bool = False
    const: Any = None


def option(
    default: Any = dataclasses.MISSING,
    *,
    factory: Callable[[], Any] | None = None,
    **spec: Any,
) -> Any:
    """A dataclass field with a :class:`Spec` (keywords of :class:`Spec`)."""
    meta = {"spec": Spec(**spec)}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _spec(f: dataclasses.Field) -> Spec | None:
    return f.metadata.get("spec")


def _flag(f: dataclasses.Field, spec: Spec) -> str:
    return spec.flag or "--" + f.name.replace("_", "-")


def _label(f: dataclasses.Field, spec: Spec) -> str:
    return f"{f.name} ({_flag(f, spec)})" if spec.cli else f.name


def _bound(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def _range_text(spec: Spec) -> str:
    lo = "-inf" if spec.lo is None else _bound(spec.lo)
    hi = "inf" if spec.hi is None else _bound(spec.hi)
    return f"[{lo}, {hi}]"


def _check_scalar(label: str, value: Any, spec: Spec) -> Any:
    if spec.choices is not None:
        if value not in spec.choices:
            raise InputError(f"{label} must be one of {', '.join(map(str, spec.choices))}, got {value!r}")
        return value
    if spec.kind == "bool":
        if not isinstance(value, bool):
            raise InputError(f"{label} must be true or false, got {value!r}")
        return value
    if spec.kind == "str":
        if not isinstance(value, str) or not value:
            raise InputError(f"{label} must be a non-empty string, got {value!r}")
        return value
    if spec.kind in ("int", "float"):
        what = "an integer" if spec.kind == "int" else "a number"
        number = _number(value, spec.kind)
        if number is None:
            raise InputError(f"{label} must be {what} in {_range_text(spec)}, got {value!r}")
        if (spec.lo is not None and number < spec.lo) or (spec.hi is not None and number > spec.hi):
            raise InputError(f"{label} must be {what} in {_range_text(spec)}, got {number:g}")
        return number
    return value


def _number(value: Any, kind: str) -> int | float | None:
    """``value`` as an int (kind ``"int"``) or a finite float, or None when it is not one."""
    if isinstance(value, bool):
        return None
    if kind == "int":
        return int(value) if isinstance(value, (int, np.integer)) else None
    if not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(float(value)):
        return None
    return float(value)


def validate(obj: Any) -> None:
    """Check and normalise every :func:`option` field of the dataclass instance ``obj`` in place."""
    for f in dataclasses.fields(obj):
        spec = _spec(f)
        if spec is None:
            continue
        value = getattr(obj, f.name)
        label = _label(f, spec)
        if value is None and spec.optional:
            continue
        value = _check_scalar(label, value, spec)
        if spec.check is not None:
            value = spec.check(label, value)
        object.__setattr__(obj, f.name, value)


def _default_of(f: dataclasses.Field) -> Any:
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return dataclasses.MISSING


def _show(spec: Spec, value: Any) -> str:
    if spec.show is not None:
        return spec.show(value)
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "on" if value else "off"
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def option_help(f: dataclasses.Field) -> str:
    """The ``--help`` text of a field: help, unit or choices, and the real default."""
    spec = _spec(f)
    assert spec is not None
    text = spec.help
    if spec.choices is not None:
        text += f" ({'|'.join(map(str, spec.choices))})"
    elif spec.unit:
        text += f" ({spec.unit})"
    default = _default_of(f)
    if default is not dataclasses.MISSING:
        text += f" [default: {_show(spec, default)}]"
    return text.replace("%", "%%")


def add_options(
    parser: argparse.ArgumentParser | Any,
    cls: type,
    *,
    exclude: Iterable[str] = (),
    title: str | None = None,
) -> None:
    """Register one flag per :func:`option` field of ``cls`` (``default=SUPPRESS``: absent flags keep the field default).

    Parameters
    ----------
    parser : argparse.ArgumentParser
    cls : dataclass type
    exclude : iterable of str
        Field names not to register (the command sets them itself).
    title : str, optional
        Put the flags in an argument group with this title.
    """
    skip = set(exclude)
    target = parser.add_argument_group(title) if title else parser
    for f in dataclasses.fields(cls):
        spec = _spec(f)
        if spec is None or not spec.cli or f.name in skip:
            continue
        flag = _flag(f, spec)
        if spec.kind == "bool":
            target.add_argument(
                flag, dest=f.name, action=argparse.BooleanOptionalAction, default=argparse.SUPPRESS, help=option_help(f)
            )
            continue
        metavar = spec.metavar or ("|".join(map(str, spec.choices)) if spec.choices else f.name.upper())
        bare = {} if spec.const is None else {"nargs": "?", "const": spec.const}
        target.add_argument(flag, dest=f.name, default=argparse.SUPPRESS, metavar=metavar, help=option_help(f), **bare)


def _parse(f: dataclasses.Field, spec: Spec, text: Any) -> Any:
    if not isinstance(text, str):
        return text
    if spec.optional and text.lower() in ("none", "auto", ""):
        return None
    if spec.parse is not None:
        try:
            return spec.parse(text)
        except InputError as exc:
            raise InputError(f"{_flag(f, spec)}: {exc}") from None
    if spec.kind == "int":
        try:
            return int(text)
        except ValueError:
            raise InputError(f"{_label(f, spec)} must be an integer in {_range_text(spec)}, got {text!r}") from None
    if spec.kind == "float":
        try:
            return float(text)
        except ValueError:
            raise InputError(f"{_label(f, spec)} must be a number in {_range_text(spec)}, got {text!r}") from None
    return text


def from_args(cls: type, args: argparse.Namespace | Mapping[str, Any], **fixed: Any) -> Any:
    """Build ``cls`` from parsed arguments: the flags given, ``fixed`` values, defaults for the rest."""
    given = vars(args) if isinstance(args, argparse.Namespace) else dict(args)
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        spec = _spec(f)
        if spec is None or f.name in fixed or f.name not in given:
            continue
        kwargs[f.name] = _parse(f, spec, given[f.name])
    return cls(**kwargs, **fixed)


def parse_pairs(text: str) -> dict[str, float]:
    """``"colour=4,depth=8"`` -> ``{"colour": 4.0, "depth": 8.0}``."""
    out: dict[str, float] = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        key, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = None
        if not sep or not key.strip() or number is None:
            raise InputError(f"expected NAME=NUMBER,... (e.g. colour=4,depth=8), got {text!r}")
        out[key.strip()] = number
    return out


def parse_tuple(n: int, kind: type = float) -> Callable[[str], tuple]:
    """A parser of ``n`` comma-separated numbers, e.g. ``"3,1"`` -> ``(3.0, 1.0)``."""

    def parse(text: str) -> tuple:
        parts = [p.strip() for p in text.split(",")]
        try:
            values = tuple(kind(p) for p in parts)
        except ValueError:
            values = ()
        if len(values) != n:
            raise InputError(f"expected {n} comma-separated numbers, got {text!r}")
        return values

    return parse
