"""LAPACK's tridiagonal solver (dgtsv) for the quasi-static engine, without `import scipy.linalg`.

Why: `scipy.linalg` imports its whole package on first use (decompositions, matrix functions,
the array-API layer, which pulls in `unittest`, `email` and `importlib.metadata`): ~0.27 s of
CPU in every quasi-static `rodctl simulate`, of which the engine uses one f2py routine. That
routine lives in the extension module `scipy.linalg._flapack`, which needs numpy and nothing of
its package: it is loaded here from scipy's own folder under its own name, so a later
`import scipy.linalg` finds it in `sys.modules` and uses the same module. Where that does not
work (another scipy layout), `scipy.linalg.get_lapack_funcs`, the same routine.
"""

from __future__ import annotations

import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from typing import Any

_NAME = "scipy.linalg._flapack"


def dgtsv() -> Any:
    """LAPACK's dgtsv as scipy wraps it: `(dl, d, du, x, info) = dgtsv(dl, d, du, b)`."""
    module = sys.modules.get(_NAME) or _load_flapack()
    if module is not None and hasattr(module, "dgtsv"):
        return module.dgtsv
    from scipy.linalg import get_lapack_funcs  # noqa: PLC0415 (the fallback: module docstring)

    return get_lapack_funcs("gtsv", dtype="float64")


def _load_flapack() -> Any:
    """`scipy.linalg._flapack` loaded from its file, or None (no such file, it fails to load)."""
    try:
        import scipy  # noqa: PLC0415 (the package alone: ~0.01 s)

        folder = Path(scipy.__file__).parent / "linalg"
        for suffix in importlib.machinery.EXTENSION_SUFFIXES:
            path = folder / f"_flapack{suffix}"
            if path.is_file():
                break
        else:
            return None
        loader = importlib.machinery.ExtensionFileLoader(_NAME, str(path))
        spec = importlib.util.spec_from_file_location(_NAME, path, loader=loader)
        if spec is None:
            return None
        module = importlib.util.module_from_spec(spec)
        loader.exec_module(module)
    except Exception:  # noqa: BLE001 - any failure: the public route instead
        return None
    sys.modules.setdefault(_NAME, module)
    return sys.modules[_NAME]
