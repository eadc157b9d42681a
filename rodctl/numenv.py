"""The numeric environment a run was made in: CPU, numeric libraries, their builds and kernels.

Why: floating-point results can depend on more than the code and the config. The BLAS/LAPACK
kernel numpy and scipy pick at load time (OpenBLAS chooses one per CPU model, or from
`OPENBLAS_CORETYPE`), the SIMD paths numpy and OpenCV dispatch at run time (per CPU feature set,
or as limited by `NPY_DISABLE_CPU_FEATURES` / `OPENCV_CPU_DISABLE`) and the number of threads of
a threaded reduction can all change the last bits of a result. rodctl's per-step path avoids the
ones it can (`rodctl.fixedla`), but a run still records where it was made, so that
`rodctl replay --verify` can show two environments side by side when a rerun differs, and a
reader can tell a real change from a different floating-point kernel.

Cheap by design (it is called once per run, before the first step): torch is *not* imported to
describe it; its build is read only when torch is already loaded, otherwise only its version.
"""

from __future__ import annotations

import functools
import os
import platform
import sys
from importlib import metadata
from typing import Any

__all__ = ["numeric_environment", "flatten", "environment_differences"]

#: CPU flags that select different SIMD or BLAS code paths (x86-64 and aarch64 names).
_CPU_FLAGS = (
    "sse2",
    "sse3",
    "ssse3",
    "sse4_1",
    "sse4_2",
    "avx",
    "f16c",
    "fma",
    "avx2",
    "avx512f",
    "avx512dq",
    "avx512cd",
    "avx512bw",
    "avx512vl",
    "avx512_vnni",
    "avx512_bf16",
    "amx_tile",
    "asimd",
    "sve",
    "sve2",
)

#: Environment variables that change numeric kernels, SIMD dispatch or thread counts.
_ENV_VARS = (
    "OPENBLAS_CORETYPE",
    "OPENBLAS_NUM_THREADS",
    "OPENBLAS_VERBOSE",
    "OMP_NUM_THREADS",
    "MKL_NUM_THREADS",
    "MKL_CBWR",
    "MKL_ENABLE_INSTRUCTIONS",
    "NPY_DISABLE_CPU_FEATURES",
    "NPY_ENABLE_CPU_FEATURES",
    "OPENCV_CPU_DISABLE",
    "ATEN_CPU_CAPABILITY",
)


def _cpu() -> dict[str, Any]:
    """CPU model, architecture, logical cores and the SIMD flags that matter."""
    info: dict[str, Any] = {
        "machine": platform.machine(),
        "model": platform.processor() or "",
        "logical_cores": os.cpu_count(),
    }
    flags: set[str] = set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                key, _, value = line.partition(":")
                key = key.strip().lower()
                if key in ("model name", "cpu model") and not info["model"].strip():
                    info["model"] = value.strip()
                elif key in ("flags", "features") and not flags:
                    flags = set(value.split())
                if info["model"] and flags:
                    break
    except OSError:  # not Linux: platform.processor() is all there is
        pass
    if flags:
        info["flags"] = [f for f in _CPU_FLAGS if f in flags]
    return info


def _numpy() -> dict[str, Any]:
    """numpy's version, its SIMD baseline and the dispatched features this CPU enables."""
    import numpy as np

    out: dict[str, Any] = {"version": np.__version__}
    try:
        # a private module, absent from numpy's stubs
        from numpy._core import _multiarray_umath as mu  # type: ignore[attr-defined]
    except ImportError:  # pragma: no cover - numpy 1.x
        from numpy.core import _multiarray_umath as mu
    out["simd_baseline"] = list(getattr(mu, "__cpu_baseline__", []))
    features = getattr(mu, "__cpu_features__", {})
    dispatch = getattr(mu, "__cpu_dispatch__", [])
    out["simd_dispatched"] = [f for f in dispatch if features.get(f)]
    return out


def _blas() -> list[dict[str, Any]]:
    """Every BLAS/OpenMP library loaded in this process: vendor, version, kernel, threads."""
    try:
        from threadpoolctl import threadpool_info
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        return [{"error": "threadpoolctl not installed"}]
    keep = ("user_api", "internal_api", "version", "architecture", "threading_layer")
    libs = []
    for lib in threadpool_info():
        row = {k: lib.get(k) for k in keep if lib.get(k) is not None}
        row["num_threads"] = lib.get("num_threads")
        row["library"] = os.path.basename(str(lib.get("filepath", "")))
        libs.append(row)
    return sorted(libs, key=lambda r: (str(r.get("user_api")), r["library"]))


def _opencv() -> dict[str, Any]:
    """OpenCV's version, threads and the CPU features its dispatched code may use here."""
    try:
        import cv2
    except ImportError:  # pragma: no cover - OpenCV is a dependency
        return {"version": None}
    out: dict[str, Any] = {
        "version": cv2.__version__,
        "threads": cv2.getNumThreads(),
        "optimized": bool(cv2.useOptimized()),
    }
    line = getattr(cv2, "getCPUFeaturesLine", None)
    if line is not None:
        out["cpu_features"] = line()
    for row in cv2.getBuildInformation().splitlines():
        key, _, value = row.strip().partition(":")
        if key in ("Baseline", "Dispatched code generation"):
            out["build_" + key.split()[0].lower()] = value.strip()
    return out


def _torch() -> dict[str, Any]:
    """torch's version; its threads and build only when torch is already imported."""
    try:
        version = metadata.version("torch")
    except metadata.PackageNotFoundError:
        return {"version": None}
    out: dict[str, Any] = {"version": version}
    torch = sys.modules.get("torch")
    if torch is not None:
        out["threads"] = torch.get_num_threads()
        out["cpu_capability"] = torch.backends.cpu.get_cpu_capability()
        out["mkl"] = bool(torch.backends.mkl.is_available())
        out["mkldnn"] = bool(torch.backends.mkldnn.is_available())
    return out


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


@functools.cache
def numeric_environment() -> dict[str, Any]:
    """Describe the numeric environment of this process (JSON-serialisable, stable key order).

    Returns:
        {"python", "platform", "cpu": {machine, model, logical_cores, flags},
         "numpy": {version, simd_baseline, simd_dispatched}, "blas": [{user_api, internal_api,
         version, architecture (the OpenBLAS kernel), threading_layer, num_threads, library}],
         "opencv": {version, threads, optimized, cpu_features, build_baseline, build_dispatched},
         "torch": {version[, threads, cpu_capability, mkl, mkldnn]}, "scipy", "pymunk",
         "env": {the variables that change kernels or threads, when set}}.
    """
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": _cpu(),
        "numpy": _numpy(),
        "blas": _blas(),
        "opencv": _opencv(),
        "torch": _torch(),
        "scipy": _version("scipy"),
        "pymunk": _version("pymunk"),
        "env": {k: os.environ[k] for k in _ENV_VARS if k in os.environ},
    }


def flatten(env: Any, prefix: str = "") -> dict[str, Any]:
    """A nested environment as {dotted.key: leaf}; list items keyed by index (blas.0.version)."""
    out: dict[str, Any] = {}
    if isinstance(env, dict):
        for k, v in env.items():
            out.update(flatten(v, f"{prefix}{k}."))
    elif isinstance(env, list) and env and all(isinstance(v, dict) for v in env):
        for i, v in enumerate(env):
            out.update(flatten(v, f"{prefix}{i}."))
    else:
        out[prefix.rstrip(".")] = env
    return out


def environment_differences(
    a: dict[str, Any] | None, b: dict[str, Any] | None
) -> list[tuple[str, Any, Any]]:
    """The entries where two environments differ, as (dotted key, a's value, b's value).

    A missing environment (an old log) counts as unknown: every key of the other is listed
    against None.
    """
    fa, fb = flatten(a or {}), flatten(b or {})
    keys = list(fa) + [k for k in fb if k not in fa]
    return [(k, fa.get(k), fb.get(k)) for k in keys if fa.get(k) != fb.get(k)]
