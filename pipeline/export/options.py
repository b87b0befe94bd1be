"""The options of ``qsls export`` and ``qsls replay`` (and of the ``export:`` / ``replay:`` sections
of a config file), apart from the code generators and the bag writer, so that the command line
reads them without the synthesis stack or rosbags."""

from __future__ import annotations

import keyword
import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from qsls.pipeline.core.config import Seed
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
    """What to generate: c (C99, a header and a source) or python (a stdlib module)."""
    precision: Literal["double", "float"] = "double"
    """``double``, or ``float``: single precision for a microcontroller with a
    single-precision FPU (C only)."""
    prefix: str = "qsls_ctrl"
    """C names: ``PREFIX_t``, ``PREFIX_step`` ..., files ``PREFIX.h``/``PREFIX.c``/``PREFIX.py``."""
    allow_uncertified: bool = False
    """Export a controller whose status is not ``certified``."""
    verify_ticks: int = Field(10_000, ge=0, le=10_000_000)
    """Random ticks of the check against the Python realization (0: no check)."""
    closed_loop_ticks: int = Field(2_000, ge=0, le=10_000_000)
    """Ticks of the float-vs-double closed-loop check (``precision: float``)."""
    seed: Seed = 0
    """Seed of the check's random ticks."""
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


class ReplayOptions(LimitOptions):
    """Options of ``qsls replay``."""

    vio_topic: str | None = None
    """The VIO topic (``nav_msgs/Odometry`` or a pose type); default: the only one there is."""
    reference: str = "hover"
    """``KIND[:key=value,...]`` (circle, hover, figure8 with the simulator's reference options,
    e.g. ``circle:radius=1,period=5,height=1``) or a YAML file."""
    reference_t0: float = 0.0
    """The reference's time at the first tick (s)."""
    backend: Literal["python", "c"] = "python"
    """Which exported code runs: the stdlib Python module or the compiled C (ctypes)."""
    allow_uncertified: bool = False
    """Replay a controller whose status is not ``certified``."""
    stamp: Literal["header", "log"] = "header"
    """Time of a message: its header stamp or the bag's log time."""
    vio_velocity_frame: Literal["body", "world"] = "body"
    """Frame of the Odometry twist: body (ROS convention) or world (VINS-style)."""
    max_gap: float = Field(0.25, gt=0)
    """Never interpolate across a gap longer than this (s)."""
    velocity_window: float = Field(0.1, gt=0)
    """Window of the smoothing differentiator (s)."""
    drop_nonfinite: bool = False
    """Skip messages with NaN/inf values instead of stopping."""
    max_tilt_deg: float = Field(20.0, gt=0, lt=90)
    """Tilt limit of the replay's report (deg): commands beyond it are counted."""
    thrust_band: tuple[float, float] = (0.5, 1.5)
    """Thrust band of the replay's report, ``LOW,HIGH`` in multiples of the hover thrust
    ``m g``."""
    hover_thrust: float = Field(0.5, gt=0, le=1)
    """mavros' normalized thrust at hover (PX4's MPC_THR_HOVER): ``thrust = this * T / (m g)``."""
    command_topic: str = "/mavros/setpoint_raw/attitude"
    """Topic of the commands written (mavros AttitudeTarget)."""
    frame_id: str = "map"
    """``frame_id`` of the commands written."""
    align: Literal["4dof", "none"] = "4dof"
    """How the VIO stream is put into the reference's frame: ``4dof`` fits a yaw and a
    translation (VIO's unobservable gauge, as ``qsls ingest --align 4dof``) of the whole
    recording onto the reference; ``none`` takes the VIO frame as the reference's."""
    vio_to_reference: tuple[float, float, float, float] | None = None
    """A known transform instead of ``align``'s fit: ``x, y, z, yaw_deg`` with
    ``p_ref = Rz(yaw) p_vio + [x y z]``; default: none (``align``)."""
    warn_deviation_m: float = Field(0.5, gt=0)
    """Warn when the first tick's position deviation from the reference exceeds this (m)."""

    @model_validator(mode="after")
    def _band(self) -> ReplayOptions:
        lo, hi = self.thrust_band
        if not 0 <= lo < hi:
            raise ValueError(f"thrust_band must be 0 <= low < high, got {self.thrust_band}")
        return self
