"""rodctl: an experiment runner for vision-based shape servoing of elastic rods.

Importing rodctl registers the Gymnasium environment `rodctl/ShapeServo-v0` (lazily: the
environment module is imported only when `gymnasium.make` builds one). Without importing rodctl
first, `gymnasium.make("rodctl:rodctl/ShapeServo-v0")` imports it.
"""

__version__ = "0.2.0"

ENV_ID = "rodctl/ShapeServo-v0"


def _register_env() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="rodctl.env:ShapeServoEnv")


_register_env()
