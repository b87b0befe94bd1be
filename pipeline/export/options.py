"""The options of ``qsls export`` (and of an ``export:`` section of a config file), apart from
the code generators so that the command line reads them without the synthesis stack."""

from __future__ import annotations

import keyword
import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from qsls.pipeline.export.attitude import LimitOptions

PREFIX_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,40}$")
"""A prefix the generated C and Python names can carry (``PREFIX_t``, ``PREFIX_step``, ...)."""
C_KEYWORDS = frozenset(
    [
        "auto",
        "break",
        "case",
        "char",
        "const",
        "continue",
        "default",
        "do",
        "double",
        "else",
        "enum",
        "extern",
        "float",
        "for",
        "goto",
        "if",
        "inline",
        "int",
        "long",
        "register",
        "restrict",
        "return",
        "short",
        "signed",
        "sizeof",
        "static",
        "struct",
        "switch",
        "typedef",
        "union",
        "unsigned",
        "void",
        "volatile",
        "while",
        "_Bool",
        "_Complex",
        "_Imaginary",
        "_Alignas",
        "_Alignof",
        "_Atomic",
        "_Generic",
        "_Noreturn",
        "_Static_assert",
        "_Thread_local",
    ]
)
"""C99 and C11 keywords, refused as ``--prefix``: the prefix alone is the state's struct tag
(``struct PREFIX``), so a keyword fails to compile."""


class ExportOptions(LimitOptions):
    """Options of ``qsls export``."""

    target: Literal["c", "python"] = "c"
    precision: Literal["double", "float"] = "double"
    """``float``: single precision for a microcontroller with a single-precision FPU (C only)."""
    prefix: str = "qsls_ctrl"
    """C names: ``PREFIX_t``, ``PREFIX_step`` ..., files ``PREFIX.h``/``PREFIX.c``/``PREFIX.py``."""
    allow_uncertified: bool = False
    verify_ticks: int = Field(10_000, ge=0)
    """Random ticks of the check against the Python realization (0: no check)."""
    closed_loop_ticks: int = Field(2_000, ge=0)
    """Ticks of the float-vs-double closed-loop check (``precision: float``)."""
    seed: int = Field(0, ge=0)
    compiler: str | None = None
    """C compiler for the check (default ``$CC``, ``cc``, ``gcc``, ``clang``)."""
    @field_validator("prefix")
    @classmethod
    def _prefix(cls, v: str) -> str:
        if not PREFIX_RE.match(v):
            raise ValueError(
                "not a C identifier (letters, digits, '_', not starting with a digit, "
                "at most 41 characters)"
            )
        if v in C_KEYWORDS or keyword.iskeyword(v):
            lang = "C" if v in C_KEYWORDS else "Python"
            raise ValueError(f"'{v}' is a {lang} keyword; choose another name, e.g. '{v}_ctrl'")
        if v.startswith("__") or (v.startswith("_") and v[1:2].isupper()):
            raise ValueError(
                f"'{v}' is reserved in C (a leading '__' or '_' and a capital); "
                "start the prefix with a letter"
            )
        return v

    @model_validator(mode="after")
    def _float_is_c(self) -> ExportOptions:
        if self.precision == "float" and self.target != "c":
            raise ValueError("precision 'float' applies to --target c (Python floats are doubles)")
        return self
