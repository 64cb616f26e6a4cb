"""The numerical environment of a result: threads, CPU kernels and library versions.

Besides its inputs, three things decide the last bits of a float64 fit:

* **threads**: a sum split over threads is added in another order. :func:`single_threaded` runs a
  block with one thread in every BLAS and OpenMP library loaded (through threadpoolctl, whatever
  the BLAS: OpenBLAS, MKL, BLIS; scipy's own OpenBLAS is loaded first) and in torch's intra-op
  pool.
* **CPU kernels**: OpenBLAS, MKL (inside torch), torch's vectorized kernels and numpy's SIMD
  loops each pick code for the CPU when they load (AVX2 here, AVX-512 elsewhere), and the kernels
  sum in different orders and round transcendental functions differently.
  :func:`pin_portable_kernels` asks every one of them for its AVX2 code on any x86-64 CPU that
  has AVX2, before they load; it is what the CLI does first.
* **versions**: pinned by ``constraints.txt`` (used by ``.ci/install``).

:func:`environment` records all three beside a result (``table.json``'s ``environment``).
Nothing here imports numpy or torch: the kernels must be pinned before they load.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import sys
import threading
import warnings
from importlib import metadata

# Each library's switch for its AVX2 code path, read once when the library loads.
PORTABLE_KERNELS = {
    "OPENBLAS_CORETYPE": "Haswell",         # OpenBLAS (numpy's and scipy's): AVX2 kernels
    "MKL_CBWR": "AVX2",                     # MKL (torch's BLAS): conditional numerical reproducibility
    "ATEN_CPU_CAPABILITY": "avx2",          # torch's own vectorized kernels
    "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",  # numpy's AVX-512 loops
}
NATIVE_SWITCH = "CLM_SIM_NATIVE_KERNELS"
"""Set to 1 to let every library pick its own kernels for the CPU (faster on AVX-512, other bits)."""

_HEAVY = ("numpy", "scipy", "torch")
# Every library's thread count, read when the library loads.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                    "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS", "NUMBA_NUM_THREADS")


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or what :mod:`platform` knows."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def pin_portable_kernels() -> str:
    """Ask the numerical libraries for their AVX2 kernels, where that is possible and wanted.

    Returns what holds for this process: ``"portable"`` (set now, before numpy, scipy and torch
    loaded; inherited by worker processes), ``"native"`` (not x86-64 with AVX2 and FMA, or
    ``CLM_SIM_NATIVE_KERNELS=1``), or ``"unpinned"`` (a numerical library was loaded already: too
    late). A variable the user set is left as it is.
    """
    if os.environ.get(NATIVE_SWITCH, "") not in ("", "0"):
        return "native"
    if platform.machine().lower() not in ("x86_64", "amd64") or not {"avx2", "fma"} <= _cpu_flags():
        return "native"
    if any(name in sys.modules for name in _HEAVY):
        return "unpinned"
    for key, value in PORTABLE_KERNELS.items():
        os.environ.setdefault(key, value)
    return "portable"


def one_thread_per_process() -> bool:
    """Before numpy, scipy or torch load: every library of this process computes on one thread
    (:data:`THREAD_VARIABLES` set to 1, whatever they were). clm-sim runs its parallel work in
    worker processes, each on one thread; a sum a library splits over its threads comes out in
    another order, so without this a command's last digits followed the machine's cores or the
    caller's ``OPENBLAS_NUM_THREADS`` wherever it had no :func:`single_threaded` block of its
    own. Returns False, and does nothing, once
    a numerical library is loaded (in-process callers: the blocks around fits, the LIP and
    the diagnosis hold there)."""
    if any(name in sys.modules for name in _HEAVY):
        return False
    os.environ.update({k: "1" for k in THREAD_VARIABLES})
    return True


def kernels() -> dict:
    """The kernels in use now: OpenBLAS's core type per library, torch's CPU capability, MKL's
    code branch, numpy's enabled SIMD groups (libraries not loaded are left out)."""
    out: dict = {}
    try:
        import threadpoolctl
        # sorted: threadpoolctl lists the loaded libraries in load order, which varies
        out["blas"] = sorted(([{k: info.get(k) for k in ("internal_api", "version",
                                                          "architecture")}
                               | {"library": os.path.basename(info["filepath"])}
                               for info in threadpoolctl.threadpool_info()
                               if info["user_api"] == "blas"]),
                             key=lambda d: json.dumps(d, sort_keys=True, default=str))
    except ImportError:
        pass
    if "torch" in sys.modules:
        torch = sys.modules["torch"]
        out["torch_cpu_capability"] = torch.backends.cpu.get_cpu_capability()
        out["mkl_cbwr"] = os.environ.get("MKL_CBWR", "default")
    if "numpy" in sys.modules:
        try:
            from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
            out["numpy_simd"] = [f for f in __cpu_dispatch__ if __cpu_features__.get(f)]
        except ImportError:  # numpy's private layout moved
            pass
    return out


def versions() -> dict[str, str]:
    """Installed versions of Python and every library that computes a number here."""
    out = {"python": platform.python_version()}
    for dist in ("clm-sim", "numpy", "scipy", "control", "numba", "llvmlite", "torch",
                 "threadpoolctl", "matplotlib", "pyyaml"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


def environment() -> dict:
    """What a result's last bits depend on besides its config: versions, CPU, kernels."""
    return {"versions": versions(), "cpu": cpu_model(), "machine": platform.machine(),
            "kernels_pinned": pin_state(), "kernels": kernels()}


def pin_state() -> str:
    """``portable`` when every variable of :data:`PORTABLE_KERNELS` holds its value, else
    ``native``."""
    return ("portable" if all(os.environ.get(k) == v for k, v in PORTABLE_KERNELS.items())
            else "native")


_lock = threading.Lock()
_depth = 0
_first: list = []  # what the first block to enter changed, undone by the last to leave


@contextlib.contextmanager
def single_threaded():
    """Run the block with one thread in every BLAS and OpenMP library and in torch.

    torch's intra-op pool and OpenBLAS's thread count are process-wide: nested blocks and blocks in
    several threads of one process share them. The first block to enter sets them and the last to
    leave restores them, so fits running in threads of one process never reset each other's
    limits. (threadpoolctl lets only the thread that set OpenBLAS's count change it again; the
    last block to leave is usually in that thread, and where it is not, the count is restored once
    that thread has ended.) OpenMP's count is a per-thread setting (``omp_set_num_threads`` acts
    on the calling thread), so every thread that enters sets and restores its own.
    """
    global _depth
    with _lock:
        if _depth == 0:
            _first.clear()
            _load_scipy_blas()
            if "torch" in sys.modules:
                torch = sys.modules["torch"]
                before = torch.get_num_threads()
                torch.set_num_threads(1)
                _first.append(lambda: torch.set_num_threads(before))
            blas = _limit("blas")
            if blas is not None:
                _first.append(lambda: blas.__exit__(None, None, None))
                _warn_if_held()
        _depth += 1
    omp = _limit("openmp")
    try:
        yield
    finally:
        if omp is not None:
            omp.__exit__(None, None, None)
        with _lock:
            _depth -= 1
            if _depth == 0:
                for undo in reversed(_first):
                    undo()
                _first.clear()


def _load_scipy_blas() -> None:
    """Load scipy's own OpenBLAS (it comes with ``scipy.linalg``) before the limit is set: a
    library loaded inside the block escapes it, and a block that first used scipy there ran its
    sums on every core. Only in a
    process that has numpy already: this module imports no numerical library by itself."""
    if "numpy" in sys.modules and "scipy.linalg" not in sys.modules:
        with contextlib.suppress(ImportError):
            import scipy.linalg  # noqa: F401


def _warn_if_held() -> None:
    """Say so when a BLAS still runs more than one thread inside the block: threadpoolctl lets
    only the thread that first set OpenBLAS's process-wide count change it while that thread
    lives, so a limit the main thread set (``threadpool_limits(4)``, never undone) holds in
    every other thread, and a fit there runs on that many threads: its sums in another order,
    its last bits not those of the same fit elsewhere."""
    import threadpoolctl

    libs = _controller(threadpoolctl).select(user_api="blas").lib_controllers
    held = [f"{lib.internal_api} {lib.num_threads}" for lib in libs if lib.num_threads > 1]
    if held:
        warnings.warn(
            f"clm_sim.numerics.single_threaded: BLAS still runs several threads in this block "
            f"({', '.join(held)}): another thread holds threadpoolctl's control of its count "
            f"(a threadpool_limits set in the main thread and not undone?); fits here may not "
            f"give the bits they give in the main thread or in a worker process",
            RuntimeWarning, stacklevel=4)


def _limit(user_api: str):
    """One thread for ``user_api`` ("blas" or "openmp"), entered (``__exit__`` restores), or
    None without threadpoolctl."""
    try:
        import threadpoolctl
    except ImportError:  # a declared dependency; without it only torch is pinned
        return None
    return _controller(threadpoolctl).limit(limits=1, user_api=user_api).__enter__()


_controllers: dict = {}
_scan_lock = threading.Lock()


def _controller(threadpoolctl):
    """threadpoolctl's view of the loaded libraries, scanned again only after an import: a scan
    (every shared object of the process) cost 5 ms, twice per block, and a table replays every
    fitted network inside a block."""
    key = len(sys.modules)  # a library loaded since the last scan came with a new module
    with _scan_lock:
        ctl = _controllers.get(key)
        if ctl is None:
            _controllers.clear()
            ctl = _controllers[key] = threadpoolctl.ThreadpoolController()
    return ctl


def available_memory_bytes() -> int | None:
    """Memory this process may still allocate (bytes): the kernel's ``MemAvailable`` estimate,
    capped by a cgroup's limit less its usage (a container); ``None`` where neither is known."""
    found = []
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
    with contextlib.suppress(OSError, ValueError):
        with open("/sys/fs/cgroup/memory.max") as fh:
            limit = fh.read().strip()
        if limit != "max":
            with open("/sys/fs/cgroup/memory.current") as fh:
                found.append(int(limit) - int(fh.read().strip()))
    if not found:
        with contextlib.suppress(OSError, ValueError, AttributeError):
            found.append(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    return max(min(found), 0) if found else None
