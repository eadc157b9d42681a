"""The simulated rod: a pymunk chain validated against the planar elastica.

`RodSim` is what the experiment loop drives (gripper moves, settling, workspace safety,
ground-truth centreline, and the mid-run changes of `rodctl/events.py`); `RodChain` is the bare
physics (optionally with in-plane gravity or table friction), also built directly by the
validation tests (free end, dead tip load, self-weight); `rodctl.sim.elastica` holds the
continuum reference solutions, the heavy elastica included.
"""

from rodctl.sim.chain import RodChain, first_mode_rate, stable_dt_limit
from rodctl.sim.quasistatic import QuasiStaticSim  # registers rod.engine "quasistatic"
from rodctl.sim.rod import ApplyResult, RodHealth, RodSim, resample_polyline

__all__ = [
    "ApplyResult",
    "RodChain",
    "RodHealth",
    "QuasiStaticSim",
    "RodSim",
    "first_mode_rate",
    "resample_polyline",
    "stable_dt_limit",
]
