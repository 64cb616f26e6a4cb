"""Compile exported C with the system compiler and call it through ctypes (tests, benchmark,
and a user's own check of an export). Not needed on the target."""

from __future__ import annotations

import ctypes
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np


def compiler() -> str | None:
    """The C compiler (``$CC``, else gcc, cc or clang on the PATH), or ``None``."""
    for name in (os.environ.get("CC"), "gcc", "cc", "clang"):
        if name and shutil.which(name):
            return name
    return None


class CompiledFeedforward:
    """``clm_ff`` of an exported folder compiled as a shared library (``flags``, default -O2).

    ``windows(B, width)`` -> forces (B,) by calling ``clm_ff`` once per row; the library stays
    loaded as long as this object lives."""

    def __init__(self, folder, flags=("-O2",), workdir=None):
        cc = compiler()
        if cc is None:
            raise RuntimeError("no C compiler (set CC, or install gcc)")
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="clm_ff_")
            workdir = self._tmp.name
        lib = Path(workdir) / "libclm_ff.so"
        folder = Path(folder)
        cmd = [cc, "-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-Wconversion",
               "-Wshadow", *flags, "-shared",
               "-fPIC", "-o", str(lib), str(folder / "clm_ff.c"), "-I", str(folder),
               str(Path(__file__).with_name("clm_ff_harness.c")), "-lm"]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode:
            raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr}")
        self.command = " ".join(cmd)
        self.lib = ctypes.CDLL(str(lib))
        dp = ctypes.POINTER(ctypes.c_double)
        self.lib.clm_ff_windows.restype = None
        self.lib.clm_ff_windows.argtypes = [dp, ctypes.c_long, ctypes.c_long, dp]
        self.lib.clm_ff_record.restype = None
        self.lib.clm_ff_record.argtypes = [dp, ctypes.c_long, dp]
        for name in ("clm_ff_time_blocks", "clm_ff_stream_time_blocks"):
            fn = getattr(self.lib, name)
            fn.restype = ctypes.c_long
            fn.argtypes = [dp, ctypes.c_long, ctypes.c_long, ctypes.c_long, dp, ctypes.c_long]
        up = ctypes.POINTER(ctypes.c_uint)
        self.lib.clm_ff_record_status.restype = ctypes.c_uint
        self.lib.clm_ff_record_status.argtypes = [dp, ctypes.c_long, ctypes.c_long,
                                                  ctypes.c_double, ctypes.c_double,
                                                  ctypes.c_int, dp, up]
        self.lib.clm_ff_eval_windows.restype = None
        self.lib.clm_ff_eval_windows.argtypes = [dp, ctypes.c_long, ctypes.c_long, dp, up]
        self.lag = int(self.lib.clm_ff_lag())
        self.lead = int(self.lib.clm_ff_lead())
        self.lib.clm_ff_count_m.restype = ctypes.c_double
        # m per count where the build reads integer counts (-DCLM_FF_FLOAT), else 0: the
        # harness rounds the metres it is given to counts, see quantized()
        self.count_m = float(self.lib.clm_ff_count_m())

    def quantized(self, r: np.ndarray) -> np.ndarray:
        """``r`` (m) as the build reads it: rounded to counts in the float build, else as is."""
        r = np.asarray(r, dtype=np.float64)
        if not self.count_m:
            return r
        c = r / self.count_m
        return np.sign(c) * np.floor(np.abs(c) + 0.5) * self.count_m  # llround's halves

    @staticmethod
    def _ptr(a: np.ndarray):
        return a.ctypes.data_as(ctypes.POINTER(ctypes.c_double))

    def __call__(self, windows: np.ndarray) -> np.ndarray:
        w = np.ascontiguousarray(windows, dtype=np.float64)
        out = np.empty(len(w))
        self.lib.clm_ff_windows(self._ptr(w), len(w), w.shape[1], self._ptr(out))
        return out

    def stream(self, r: np.ndarray) -> np.ndarray:
        """``u_ff`` of a record ``r`` (m) by the streaming form (held at its ends)."""
        r = np.ascontiguousarray(r, dtype=np.float64)
        out = np.empty(len(r))
        self.lib.clm_ff_record(self._ptr(r), len(r), self._ptr(out))
        return out

    def stream_status(self, r_padded: np.ndarray, *, start: int | None = None,
                      max_force: float | None = None, max_slew: float | None = None,
                      limits_first: bool = False, restart: bool = False):
        """The streaming form over ``r_padded`` (``r[k] = r_padded[k + lag]``, held ends
        included, any values, NaN too): started at rest (``start=None``) or from the window of
        sample ``start``; limits (N, N/s) set after that (``limits_first``: before init or
        start; ``restart``: the stream initialised at rest, its limits set, then started at
        ``start``). Returns ``(u_ff, status, init_status)``
        for the ``len(r_padded) - lag - lead`` samples (before ``start``: NaN, status 0)."""
        rp = np.ascontiguousarray(r_padded, dtype=np.float64)
        n = len(rp) - self.lag - self.lead
        out = np.full(n, np.nan)
        status = np.zeros(n, dtype=np.uintc)
        limit = -1.0 if max_force is None else float(max_force)
        slew = float("inf") if max_slew is None else float(max_slew)
        init = self.lib.clm_ff_record_status(
            self._ptr(rp), n, -1 if start is None else int(start), limit, slew,
            int(limits_first) | 2 * int(restart), self._ptr(out),
            status.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)))
        return out, status, int(init)

    def eval(self, windows: np.ndarray):
        """``clm_ff_eval`` per row of ``windows``: ``(u_ff, status)``."""
        w = np.ascontiguousarray(windows, dtype=np.float64)
        out = np.empty(len(w))
        status = np.zeros(len(w), dtype=np.uintc)
        self.lib.clm_ff_eval_windows(self._ptr(w), len(w), w.shape[1], self._ptr(out),
                                     status.ctypes.data_as(ctypes.POINTER(ctypes.c_uint)))
        return out, status

    def time_blocks(self, r: np.ndarray, repeats: int, block: int = 256,
                    stream: bool = False) -> np.ndarray:
        """ns per call of ``clm_ff`` (or per push of the streaming form), one value per block of
        ``block`` consecutive calls over ``r``, ``repeats`` times (CPU time of the thread)."""
        r = np.ascontiguousarray(r, dtype=np.float64)
        out = np.empty(repeats * (len(r) // block + 1))
        fn = self.lib.clm_ff_stream_time_blocks if stream else self.lib.clm_ff_time_blocks
        count = fn(self._ptr(r), len(r), repeats, block, self._ptr(out), len(out))
        return out[:count]
