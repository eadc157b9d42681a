"""rodctl: an experiment runner for vision-based shape servoing of elastic rods.

Importing rodctl registers the Gymnasium environment `rodctl/ShapeServo-v0` (lazily: the
environment module is imported only when `gymnasium.make` builds one), and its forms for RL
libraries `rodctl/ShapeServoRL-v0` and `rodctl/ShapeServoGoal-v0` (`rodctl.rl`, docs/rl.md).
Without importing rodctl first, `gymnasium.make("rodctl:rodctl/ShapeServo-v0")` imports it.
"""

__version__ = "0.2.0"

ENV_ID = "rodctl/ShapeServo-v0"
#: The same episodes for RL libraries: float32 vectors, normalised; and goal-conditioned (HER).
RL_ENV_ID = "rodctl/ShapeServoRL-v0"
GOAL_ENV_ID = "rodctl/ShapeServoGoal-v0"


def load_run(path, *, recover: bool = False, images: bool = True):
    """A `rodctl simulate` run read back from its MCAP log (docs/python-api.md)."""
    from rodctl.notebook import load_run as _load_run

    return _load_run(path, recover=recover, images=images)


def load_results(path):
    """The episodes of a compare, sweep or suite folder as a pandas DataFrame (pandas needed;
    docs/python-api.md)."""
    from rodctl.notebook import load_results as _load_results

    return _load_results(path)


def _register_env() -> None:
    from gymnasium.envs.registration import register, registry

    if ENV_ID not in registry:
        register(id=ENV_ID, entry_point="rodctl.env:ShapeServoEnv")
    if RL_ENV_ID not in registry:
        register(id=RL_ENV_ID, entry_point="rodctl.rl:ShapeServoRLEnv")
    if GOAL_ENV_ID not in registry:
        register(id=GOAL_ENV_ID, entry_point="rodctl.rl:ShapeServoGoalEnv")


# `rodctl simulate`: its helper processes forked first, before gymnasium (rodctl/_entry.py).
from rodctl import _entry  # noqa: E402

_entry.quiet_start()
_entry.start_helpers()
_register_env()
