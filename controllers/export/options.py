"""What an export is asked for beyond the model: the names (``prefix``), the output limits and
the trace (product version, commit, date, the model's content hash). Shared by the C and the
ONNX writers; every name and text they put into generated code goes through :func:`safe_text`
or :func:`check_prefix`."""

from __future__ import annotations

import hashlib
import os
import re
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from clm_sim.errors import UserError

DEFAULT_PREFIX = "clm_ff"
# One count of the float build's reference (an int64 fixed-point position): 1 pm. Its cost (the
# force of a reference rounded to counts) is below the sign term's own ambiguity from 1e-10 m
# down (docs/export.md); int64 counts of 1 pm reach +-2.3e6 m within CLM_FF_COUNT_MAX.
DEFAULT_COUNT_M = 1e-12
# C keywords and the C library's reserved spellings a prefix must not become.
_RESERVED = {"auto", "break", "case", "char", "const", "continue", "default", "do", "double",
             "else", "enum", "extern", "float", "for", "goto", "if", "inline", "int", "long",
             "register", "restrict", "return", "short", "signed", "sizeof", "static", "struct",
             "switch", "typedef", "union", "unsigned", "void", "volatile", "while", "main"}
_PREFIX = re.compile(r"[a-z][a-z0-9_]{0,30}")
# What may appear of a name or a description inside a C comment or an ONNX string: letters,
# digits, space and plain punctuation. No backslash (line splicing), no '?' (trigraphs such as
# ??/ are a backslash), no '*' or '/' together (comment ends), no quote, no control character.
_SAFE = re.compile(r"[^A-Za-z0-9 _.,:;=+()\[\]<>%#@^~|&!-]")


def check_prefix(prefix: str) -> str:
    """``prefix`` if it can name every public symbol (``<prefix>_...``, macros ``<PREFIX>_...``):
    a lower-case C identifier of 1 to 31 characters, not a keyword; else a ``UserError``."""
    if not isinstance(prefix, str) or not _PREFIX.fullmatch(prefix) or prefix in _RESERVED:
        raise UserError(f"--prefix: expected a lower-case C name (a letter, then letters, digits "
                        f"or _, at most 31), got {prefix!r}")
    return prefix


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def safe_text(text: str) -> str:
    """``text`` with every character outside a safe set (see ``_SAFE``) replaced by ``_``: what
    a file name or a description may put into a generated comment or string."""
    return _SAFE.sub("_", str(text))


def content_hash(path) -> str:
    """SHA-256 of the model's bytes (a PGNN: its ``.pt`` then its ``.json``), hex."""
    path = Path(path)
    digest = hashlib.sha256()
    files = [path]
    pair = [path.with_suffix(".pt"), path.with_suffix(".json")]
    if path.suffix in (".pt", ".json") and all(f.is_file() for f in pair):
        files = pair
    for f in files:
        digest.update(f.read_bytes())
    return digest.hexdigest()


def _commit() -> str:
    """The product's git commit (12 hex digits, ``-dirty`` with uncommitted changes to tracked
    files), or ``unknown`` where the product is not a checkout of its own (an installed copy that
    happens to sit inside someone else's repository must not report that one's commit)."""
    root = Path(__file__).resolve().parents[2]
    if not ((root / "pyproject.toml").is_file() and (root / "clm_sim").is_dir()):
        return "unknown"
    try:
        done = subprocess.run(["git", "-C", str(root), "describe", "--always", "--dirty",
                               "--abbrev=12", "--match=no-tag-matches-this"],
                              capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    out = done.stdout.strip()
    ok = done.returncode == 0 and re.fullmatch(r"[0-9a-f]{7,40}(-dirty)?", out)
    return out if ok else "unknown"


def export_date() -> str:
    """UTC date and time of the export; ``SOURCE_DATE_EPOCH`` (s) fixes it for reproducible
    bytes."""
    epoch = os.environ.get("SOURCE_DATE_EPOCH")
    try:
        stamp = int(epoch) if epoch is not None else time.time()
    except ValueError:
        raise UserError(f"SOURCE_DATE_EPOCH: expected whole seconds, got {epoch!r}") from None
    if not 0 <= stamp <= 253402300799:  # 9999-12-31T23:59:59Z, the last date strftime writes
        raise UserError(f"SOURCE_DATE_EPOCH: expected 0 to 253402300799 s (up to the year 9999), "
                        f"got {epoch!r}")
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(stamp))


# The limits of an export (the C's macros): output force (N), slew (N/s), the position envelope
# (m) and the velocity (m/s) and acceleration (m/s^2) envelope of what the model reads.
LIMIT_KEYS = ("max_force", "max_slew", "r_min", "r_max", "v_max", "a_max")


@dataclass(frozen=True)
class ExportOptions:
    """prefix: the names' prefix (``clm_ff``); max_force (N) and max_slew (N/s): the export's
    output limits (``None``: none); r_min, r_max (m): the position envelope (a sample outside it
    is rejected); v_max (m/s), a_max (m/s^2): the velocity and acceleration the model reads are
    cut to these (``None``: none); envelope: where the limits come from (one line); count_m
    (m): one count of the float build's reference (integer counts, as a drive's set-point);
    model_name, model_sha256, version, commit, date: the trace."""

    prefix: str = DEFAULT_PREFIX
    max_force: float | None = None
    max_slew: float | None = None
    count_m: float = DEFAULT_COUNT_M
    r_min: float | None = None
    r_max: float | None = None
    v_max: float | None = None
    a_max: float | None = None
    envelope: str = "none"
    model_name: str = "unknown"
    model_sha256: str = "unknown"
    version: str = "unknown"
    commit: str = "unknown"
    date: str = "unknown"

    def __post_init__(self):
        check_prefix(self.prefix)
        for key in ("max_force", "max_slew", "count_m", "v_max", "a_max"):
            value = getattr(self, key)
            if value is not None and not (_number(value) and 0 < float(value) < float("inf")):
                option = {"v_max": "max-velocity", "a_max": "max-acceleration"}.get(
                    key, key.replace("_", "-"))
                raise UserError(f"--{option}: expected a positive number, got {value!r}")
        ends = (self.r_min, self.r_max)
        if (None in ends) != (ends == (None, None)) or not (
                ends == (None, None) or (all(_number(x) and abs(x) < 1e300 for x in ends)
                                         and self.r_min < self.r_max)):
            raise UserError(f"--position-range: expected two finite positions, the lower "
                            f"first (m), got {self.r_min!r} {self.r_max!r}")

    def limits(self) -> dict:
        """The limits as export.json states them (``None``: none)."""
        return {key: getattr(self, key) for key in LIMIT_KEYS}

    @classmethod
    def traced(cls, model_path, **kwargs) -> "ExportOptions":
        """Options with the trace of the model file at ``model_path`` filled in."""
        from clm_sim import __version__

        path = Path(model_path)
        return cls(model_name=safe_text(path.name), model_sha256=content_hash(path),
                   version=__version__, commit=_commit(), date=export_date(), **kwargs)

    def trace(self) -> dict:
        """The trace as written into export.json and the ONNX metadata."""
        return {"product": "clm-sim", "version": self.version, "commit": self.commit,
                "date": self.date, "model_file": self.model_name,
                "model_sha256": self.model_sha256}

    def trace_line(self) -> str:
        lim = (f"; limits {self.max_force or 'none'} N, {self.max_slew or 'none'} N per s, "
               f"from {self.envelope}")
        return (f"clm-sim {self.version}, commit {self.commit}, exported {self.date}; model file "
                f"{self.model_name}, sha256 {self.model_sha256}{lim}; names {self.prefix}")
