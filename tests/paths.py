"""Repository paths shared by tests (importable because pytest puts tests/ on sys.path)."""

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONFIGS = sorted((REPO / "configs").glob("*.yaml"))

#: Configs of the example plug-in (examples/plugin/), run when the plug-in is installed.
PLUGIN_CONFIGS = sorted((REPO / "examples/plugin").glob("*.yaml"))


def plugin_installed() -> bool:
    """True when the example plug-in package is importable (`make test` installs it)."""
    import importlib.util

    return importlib.util.find_spec("rodctl_navarro") is not None
