"""Load (or compile) every numba kernel before a node joins the 1 kHz loop.

numba compiles on the first call (seconds) or loads its on-disk cache (about a
second); either would make the first samples of a run stale. Nodes call
:func:`warm_up` before they subscribe, so the plant starts the clock only once
every kernel is resident. ``dem-ros launch`` and ``dem-ros sim`` call it first in
their own process with ``progress`` (a callback given the name of what is being
compiled), so a first run compiles once, visibly, and the nodes then load the cache.
The commands that also simulate offline (``sim``, ``launch``'s comparison run, ``make``'s
set-up) warm the compiled closed loop of :func:`~dem_ros.core.simulate.simulate` too
(``offline``): it is specialised per control law and estimator, and is the longest compile
of all (minutes on a loaded 2-core machine).
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import numpy as np

from .params import default_config

__all__ = ["warm_up"]


def warm_up(progress: Callable[[str], None] | None = None,
            offline: Sequence[tuple[str | None, str | None]] = ()) -> None:
    """Call every kernel once (compiling it, or loading it from numba's cache).

    Args:
        progress: called with the name of each part before it is warmed (e.g. ``"controller adaptive"``).
        offline: (control law, estimator) pairs whose offline closed loop to warm as well
            (``simulate``'s kernel); None for either: the configured default (``controller.type``,
            ``estimator.type``).
    """
    say = progress or (lambda _what: None)
    from numba.core.errors import NumbaPerformanceWarning

    with warnings.catch_warnings():  # numba's advice on small matrix products; nothing a user can act on
        warnings.simplefilter("ignore", NumbaPerformanceWarning)
        _warm(say)
        if offline:
            _warm_offline(say, offline)


def _warm(say: Callable[[str], None]) -> None:
    from .controllers import make_controller
    from .estimator import KalmanEstimator
    from .model import hover_state, plant_vector, rk4
    from .reference import ReferenceModel

    cfg = default_config()
    say("plant model")
    x0, u0 = hover_state(cfg["plant_sim"], 0.008)
    ref = np.array([0.008, 0.008, 0, 0, 0, 0, 0, 0], float)
    for name in ("adaptive", "adaptive_enhanced", "paper", "paper_fixed", "nonlinear_decoupling", "decentralized_pid"):
        say(f"controller {name}")
        c = make_controller(cfg["controller"], name)
        c.reset(x0.copy(), u0)
        c.step(x0.copy(), ref)
    say("estimator kf")
    est = KalmanEstimator(cfg["estimator"])
    est.step(x0, u0)
    est.step(x0, u0)
    say("reference model")
    ReferenceModel(cfg["reference"]).step(np.array([0.008, 0.008]))
    say("plant integrator")
    x = x0.copy()
    rk4(x, u0, plant_vector(cfg["plant_sim"]), 1e-3, 2)
    from .plant import DemPlant

    plant = DemPlant(cfg["plant_sim"], 0.01)
    plant.measurement()
    plant.advance(plant.u0)
    from .hold import command_sample

    command_sample(1, 1)  # the simulated and the rig board's sample rule
    say("board supervisor")  # plant_sim's and the rig's board: its landing kernels load on construction
    from ..board import Supervisor

    Supervisor(cfg["plant_sim"], cfg["plant_sim"]["dt"])


def _warm_offline(say: Callable[[str], None], pairs: Sequence[tuple[str | None, str | None]]) -> None:
    from .simulate import simulate

    cfg = default_config()
    done = set()
    for law, est in pairs:
        key = (law or cfg["controller"]["type"], est or cfg["estimator"]["type"])
        if key in done:
            continue
        done.add(key)
        say(f"offline closed loop ({key[0]}, {key[1]})")
        simulate(cfg, controller=key[0], estimator=key[1], duration=2 * cfg["plant_sim"]["dt"])
