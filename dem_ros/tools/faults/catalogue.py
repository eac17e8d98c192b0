"""The fault catalogue of ``dem-ros faults``: one :class:`FaultSpec` per row, :data:`CATALOGUE` (the simulated
graph) and :data:`RIG_CATALOGUE` (hw_driver and the emulated board), what each row injects and what it allows."""

from __future__ import annotations

from .inject import (
    _bad_cdr,
    _empty_position,
    _estop,
    _future_applied,
    _non_utf8,
    _reference_step,
    _rogue_command,
    _spike,
    _stale,
)
from .spec import FaultSpec

__all__ = ["CATALOGUE", "RIG_CATALOGUE", "FaultSpec"]

_KILLED = ("levitating", "landed safely")
_RESTART_S = 15.0  # run length with a restart: a restarted node takes seconds to come up on a loaded host
CATALOGUE: tuple[FaultSpec, ...] = (
    FaultSpec("rogue-command", "1e6 V on /dem/command from a foreign writer, 50 samples", _rogue_command, 50),
    FaultSpec("empty-position", "/dem/measurement and /dem/state_estimate with an empty position, 10 samples",
              _empty_position, 10),
    FaultSpec("non-utf8-frame", "well-formed CDR with a non-UTF-8 frame_id on measurement, estimate, reference",
              _non_utf8, 10),
    FaultSpec("bad-cdr", "8 random bytes overwritten in valid samples of five topics, 20 samples", _bad_cdr, 20),
    FaultSpec("reference-step", "/dem/reference 20 mm off the stream (a foreign writer), 100 samples",
              _reference_step, 100),
    FaultSpec("spike-10mm", "one foreign /dem/measurement +10 mm at the plant's stamp", _spike(10.0), 1),
    FaultSpec("spike-50mm", "one foreign /dem/measurement +50 mm at the plant's stamp", _spike(50.0), 1),
    FaultSpec("stale-stamps", "estimates stamped 100 ms old and measurements +1 h, 20 samples", _stale, 20),
    FaultSpec("future-applied", "one foreign /dem/applied_voltage stamped +1 h (a corrupt stamp)", _future_applied, 1),
    FaultSpec("disk-full", "the bag on a 768 KiB tmpfs: the disk fills about 1.5 s into the run (S1, zstd)",
              disk_kib=768),
    FaultSpec("kill-controller", "SIGKILL the controller, restart after 0.1 s", kill="controller", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-controller-long", "SIGKILL the controller, restart after 1 s (> hold_timeout)", kill="controller",
              restart_after=1.0, allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-estimator", "SIGKILL the estimator, restart after 0.1 s", kill="estimator", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-estimator-long", "SIGKILL the estimator, restart after 1 s", kill="estimator", restart_after=1.0,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-reference", "SIGKILL the reference, restart after 0.1 s", kill="reference", restart_after=0.1,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-reference-long", "SIGKILL the reference, restart after 1 s", kill="reference", restart_after=1.0,
              allowed=_KILLED, composed=False, min_duration=_RESTART_S),
    FaultSpec("kill-recorder", "SIGKILL the recorder (not restarted)", kill="recorder", allowed=("levitating",),
              composed=False, min_duration=8.0),  # the plant node reports it 2-3 s after its last report
)



# The rig rows: `dem-ros launch --hardware rig --compose` (UDP on loopback, the emulator free-running at 1 kHz,
# controller.command_delay=2), the fault at t = --at s of the experiment. What the design makes of each
# (hw_driver.trip_samples = 3, the board's SENSOR_BLIND_SAMPLES = 5, hold_timeout = link_timeout = 50 ms,
# bus_min = 100 V; the landing law needs R i = 113 V at the support, nominal):
_DRIVER_TRIP = ("driver", "trips", 1)
RIG_CATALOGUE: tuple[FaultSpec, ...] = (
    # 2 samples out of range: below the driver's trip (3) and the board's blind limit (5): held, ridden through
    FaultSpec("dropout-short", "gap sensor 1 reads 0 counts for 2 samples (dead): held, ridden through", hardware=True,
              rig_fault="dropout:1@{t}+0.0015", reports=("sensor_holds",),
              counts=(("driver", "sensor_holds", 2), ("board", "sensor_gaps", 2))),
    # 300 ms dead: the driver trips after 3 samples, the board after 5 lands with gap 1 from coil 1's flux
    FaultSpec("dropout-long",
              "gap sensor 1 reads 0 counts for 300 ms: the driver trips, the board lands on the flux gap",
              hardware=True, rig_fault="dropout:1@{t}+0.3", allowed=("landed safely",), reports=("gap sensor 1",),
              counts=(("driver", "sensor_holds", 3), _DRIVER_TRIP, ("board", "sensor_losses", 1))),
    # a plausible frozen reading: the board's flux check finds it contradicting coil 1's flux once the plate moves
    # (the unstable plate drifts from it within ~150 ms; before the check it reached the rail) and lands on
    # that flux; GAP0_IMPLAUSIBLE trips the driver
    FaultSpec("stuck", "gap sensor 1 repeats its reading for 1 s: the board's flux check lands on coil 1's flux",
              hardware=True, rig_fault="stuck:1@{t}+1", allowed=("landed safely",),
              reports=("GAP0_IMPLAUSIBLE",), counts=(_DRIVER_TRIP, ("board", "implausible", 1))),
    # one full-scale sample: flagged out of range, held one sample by driver and board
    FaultSpec("spike", "gap sensor 1 at full scale for one sample: held, ridden through", hardware=True,
              rig_fault="spike:1@{t}", reports=("sensor_holds",),
              counts=(("driver", "sensor_holds", 1), ("board", "sensor_gaps", 1))),
    # 10 % of the sensor frames fail their CRC for 0.5 s: each one dropped and counted, the board holds a sample
    FaultSpec("corrupt", "10 % of the board's frames with a flipped byte (CRC) for 0.5 s: counted, ridden through",
              hardware=True, rig_fault="corrupt@{t}+0.5:0.1", reports=("corrupt",), counts=(("driver", "corrupt", 1),)),
    # 20 ms silent: the board holds ~21 ms (< hold_timeout): ridden through
    FaultSpec("linkloss-20ms", "nothing sent or received for 20 ms: the board holds, ridden through", hardware=True,
              rig_fault="linkloss@{t}+0.02", reports=("lost",),
              counts=(("driver", "lost", 18), ("board", "hold_events", 1))),
    # 50 ms silent = hold_timeout: the board goes without a fresh command for the loss plus a round trip
    # (51-52 samples) and the driver without a command as long: both watchdogs are at their limit, so either
    # outcome is the design's (landing the usual one); never a failure
    FaultSpec("linkloss-50ms", "nothing sent or received for 50 ms (= hold_timeout): held, then most likely landed",
              hardware=True, rig_fault="linkloss@{t}+0.05", allowed=("levitating", "landed safely"),
              reports=("lost",), counts=(("driver", "lost", 45), ("board", "hold_events", 1))),
    # a 0.2 s dip to 95 V (< bus_min): the driver trips on BUS_UNDERVOLTAGE, the board lands; the bus is back
    # before the landing needs more than 95 V (the plate is held up to ~9 mm at 95 V)
    FaultSpec("sag", "bus sags to 95 V (< bus_min 100 V) for 0.2 s: the driver trips, the board lands", hardware=True,
              rig_fault="sag@{t}+0.2:95", allowed=("landed safely",), reports=("BUS_UNDERVOLTAGE",),
              counts=(("driver", "board: BUS_UNDERVOLTAGE", 3), _DRIVER_TRIP)),
    # 95 V to the end: below the 113 V the landing law needs at the support: the plate sinks faster than
    # landing_speed onto its support, away from the rail (docs/manual/safety.md's limit; the descent is reported)
    FaultSpec("sag-sustained", "bus at 95 V to the end: landed, the last mm faster than landing_speed (design limit)",
              hardware=True, rig_fault="sag@{t}:95", allowed=("landed safely",), reports=("BUS_UNDERVOLTAGE",),
              counts=(("driver", "board: BUS_UNDERVOLTAGE", 3), _DRIVER_TRIP), descent_bounded=False),
    # coil 1's bridge open to the end: its end falls onto the support (the current decays in ~7 ms, nothing can
    # bound that descent), the board lands the other end
    FaultSpec("coil", "coil driver 1 fails open (DRIVER0_FAULT) to the end: the driver trips, the board lands",
              hardware=True, rig_fault="coil:1@{t}", allowed=("landed safely",), reports=("DRIVER0_FAULT",),
              counts=(("driver", "board: DRIVER0_FAULT", 3), _DRIVER_TRIP), descent_bounded=False),
    FaultSpec("estop", "e-stop on /dem/hw/estop (as dem-ros hw estop): the driver latches it, the board lands",
              _estop, 3, hardware=True, allowed=("landed safely",), reports=("e-stop",),
              counts=(("driver", "estops", 1),)),
    # the controller alone is killed (in a process of its own beside the container, --apart controller);
    # the driver's command watchdog and the board's hold both end after 50 ms: LAND
    FaultSpec("kill-controller", "SIGKILL the controller (not restarted): the driver's watchdog, the board lands",
              kill="controller", hardware=True, composed=False, allowed=("landed safely",),
              reports=("command watchdog",), counts=(("driver", "watchdog", 1),)),
)
