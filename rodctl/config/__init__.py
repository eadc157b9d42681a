"""Typed, validated experiment configs (pydantic v2), loaded from YAML with `--set` overrides.

One module per stage owns that stage's models; `ExperimentConfig` assembles them.
"""

from rodctl.config.experiment import ExperimentConfig
from rodctl.config.loading import (
    ConfigError,
    dump_config,
    load_config,
    read_yaml,
    validate_config,
)

__all__ = [
    "ConfigError",
    "ExperimentConfig",
    "dump_config",
    "load_config",
    "read_yaml",
    "validate_config",
]
