r"""The coil driver's safety supervisor: the board's hard limits, command watchdog and safe landing.

A plate must never hit the rail because of software, so the limits live where the
hardware is: in the board that drives the coils (the simulated board of ``plant_sim``
and the rig emulator's board of ``hw_driver`` both run this class), never in the
controller. Pure Python + numba, no middleware.

Modes (:class:`Mode`, the values of the device link's mode byte)::

    OFF --fresh command--> RUN --no fresh command--> HOLD --held > hold_timeout--> LAND --gaps >= landing_gap--> LANDED
                           RUN <--fresh command----- HOLD
    RUN/HOLD --limit trip, predicted gap trip, estop(), land(), requested LAND/OFF--> LAND   (latched)
    RUN/HOLD --a current or gap sensor without a finite sample for > SENSOR_BLIND_SAMPLES--> LAND  (latched)
    RUN/HOLD --a gap sensor that contradicts the coils' fluxes (implausible)--> LAND on its coil's flux  (latched)
    any --a gap sensor lost with no landing on its coil's flux possible (the other gap or this coil's current
          lost too, the other gap already from its flux, the current under FLUX_GAP_MIN_CURRENT, or no sample
          with both within 2 x SENSOR_BLIND_SAMPLES), a flux gap that yields nothing for > SENSOR_BLIND_SAMPLES
          before LANDED (its current lost, or under FLUX_GAP_MIN_CURRENT), or any non-finite sample while
          OFF/LANDED or before the first finite one--> FAULT (0 V)                (latched)
    LAND/LANDED/FAULT --clear()--> OFF

* **RUN**: the applied voltage is the command clipped to ``[-u_max, u_max]`` (the
  coil driver's bus; counted in ``clipped``). A coil current above ``i_max``, an
  estimated load-point gap above ``trip_gap_max``, or a *predicted stopping gap*
  below ``trip_gap_min`` (the braking bound below: where the plate would stop, at
  either end, if the board applied this command for one more sample and then
  braked) latches a fault and lands; the landing starts by braking.
* **HOLD**: a sample without a fresh command (late, lost, non-finite) holds the
  last applied voltage. Holding the voltage of an unstable plant is a small
  perturbation for a few samples only: with the voltages held the DEM has two real
  poles at +47..+62 rad/s (notes: hardware-and-realtime), a deviation grows by e
  every 17-20 ms. ``hold_timeout`` bounds it (default 50 ms: x ~15); then LAND.
* **LAND**: the landing law below lowers the plate away from the rail (a larger
  gap; y is positive down, ``dem_ros.core.model``: the magnets are above the plate
  and attract it, the rail is gap 0, gravity and the loads pull toward larger gaps)
  to ``landing_gap`` at no more than ``landing_speed``; commands are ignored until
  ``clear()``. The landing law's voltage passes the same braking check: while it
  fails, or while either end still approaches the rail after a brake, the board
  *brakes* (below) instead; when the brake releases, the landing restarts from the
  state the brake left (reference at the estimate, current integral at zero).
* **LANDED**: the plate is on its support at ``landing_gap``; the current is
  driven to zero (a 0 V cut is safe only here, never at hover).
* **FAULT**: 0 V: a gap sensor lost for good when its coil's flux cannot stand in for it, or no longer
  does (below), or a sensor sample lost while the plate rests on its support or before the observer has a
  first estimate.

Faults latch with a reason (``fault``); ``reason`` explains the current mode;
``counters`` count samples and events (``holds``, ``hold_events``, ``clipped``,
``rejected``, ``landings``, ``trips``, ``estops``, ``landed``, ``brakes``: braked samples,
``brake_events``, ``implausible``: gap sensors found contradicting the coils' fluxes,
``sensor_gaps``: samples with a non-finite or missing reading, ``sensor_gap_events``:
runs of them, ``sensor_losses``: channels given up after SENSOR_BLIND_SAMPLES, each once until it reads again) and keep ``longest_hold_us`` (the longest hold that ended without a
landing, or is still going). ``stop_gap`` (2,) [m] is the last predicted stopping gap per
end and ``min_stop_gap`` [m] the smallest one checked (both in ``snapshot()``, in mm).

The braking bound (where the plate stops if the board brakes)
--------------------------------------------------------------
Geometry: both magnets attract the plate toward the rail (smaller gap); nothing but
gravity and the loads pulls it away. So the one way to stop a plate approaching the
rail is to remove the magnets' flux, as fast as the bus allows. With the flux linkage
lambda_j = 2 K i_j / delta_j [V s] (Eq. 5's coil: u_j = R i_j + d lambda_j/dt) the force
is F_j = lambda_j^2 / (4 K) [N], a function of the flux alone, whatever the gap does.

*Brake* (the board's fast de-energise): per coil, the voltage that brings the current
to zero in one sample, ``u_j = R i_j - (2K/delta_j) i_j / T``, clipped to the available
voltage U = min(u_max, bus) [V] (the bus the board measures, when it does). While
clipped, d|lambda_j|/dt = -(U + R |i_j|) <= -U; the last sample brings it to zero
linearly, so |lambda_j(t)| <= lambda_j (1 - t/tau_j)^+ with tau_j = lambda_j / U + T [s].

*Bound*, per load point j (the other one k), from what the board has: the observer's
gap p_j [m] and rate v_j [m/s] (approach speed w_j = -v_j), the measured currents i
[A], the candidate voltage u_c (2,) [V] (the command, or the landing law's) for the
next sample, and the nominal m, K, L, l, I, N1, N2, g widened by ``BOUND_MARGIN`` e::

    K in [K_lo, K_hi] = [(1 - e) K, (1 + e) K]        (the true magnet, either side of the datasheet)
    1/m, 1/I up to (1 + e)/m, (1 + e)/I, down to (1 - e)/m, (1 - e)/I
    A_b = (1 + e)(1/m + L l/I),  B_b = max((1 + e)/m - (1 - e) L l/I, 0)   [1/kg] (the largest A, B)
    n_j = g + min(0, (1 + e)(L^2/I)(N_j - N_k))       [m/s^2] (pull away from the rail: gravity and
                                                       the loads, whatever the mass; must be > 0)
    a_j = 2 |i_j| / delta_j,  c_j = T |u_c,j|          (|d lambda/dt| <= |u| as R i opposes the flux)
    lambda+_j(K) = K a_j + c_j                        [V s]  (flux after the candidate sample)
    F+_j = max over K of lambda+_j^2 / (4 K) = max(F(K_lo), F(K_hi))   [N]
    lambda+_j = lambda+_j(K_hi)                       (the largest flux: the slowest brake)

F(K) = (K a + c)^2 / (4 K) = a^2 K/4 + a c/2 + c^2/(4 K) is convex in K, so its maximum over the
interval is at an end (the stationary point K = c/a is the minimum). At high flux (a K >> c) the
stronger magnet pulls harder; at low flux (a resting or falling plate under a large command) the
weaker one does: at 0 A, 200 V, F+ = (0.2 V s)^2/(4 K) is 18.3 N at 1.25 K but 30.5 N at 0.75 K
(a review found the bound taken at K_hi alone; tests/core/test_safety.py checks both ends)::

    G_j  = A_b F+_j + B_b F+_k                        [m/s^2] (the magnets' pull on end j)
    tau  = max(lambda+) / U + T                       [s]    (lambda+_j alone when B_b = 0)
    phase 0, the candidate sample:   a0 = G_j - n_j,  s0 = w_j^+ T + a0^+ T^2/2,  w1 = w_j + a0 T
    phase 1-2, braking: approach acceleration <= G_j (1 - t/tau)^+2 - n_j, so the approach
        speed <= w1 + G_j tau/3 - n_j t and the distance still travelled toward the rail
    D_j  = s0 + (w1 + G_j tau / 3)^+2 / (2 n_j)       [m]
    stop_gap_j = p_j - D_j                            [m]

Trip when min_j stop_gap_j < ``trip_gap_min``. Invariance: each sample checks "this
command for one sample, then brake"; when the check of sample k fails, braking from
sample k is what the check of sample k - 1 proved safe. So with the model inside the
margins, the plate stops at least ``trip_gap_min`` from the rail (``gap_min`` of the
plant, rail contact, lies below it: the rest is the estimate's error). The bound
neglects the resistive decay R i (it only helps) and bounds the magnets' pull by its
impulse G tau/3 delivered at once (over-estimates by at most G tau^2/12).

Numbers (Table 2, e = 0.25, U = 200 V, T = 1 ms, n = g): hovering at 8 mm (4.0 A) under
the 80 V hover command, lambda+ = 0.547 + 0.080 = 0.627 V s, F+ = 180 N, A_b = 0.196 /kg,
B_b = 0.017 /kg: at rest D = 0.35 mm, approaching at 45 mm/s D = 0.87 mm, at 100 mm/s
D = 1.79 mm (tests/core/test_safety.py; 0.22, 0.66, 1.49 mm before 1/I was widened). So a plate
rising at 100 mm/s is braked above 3.3 mm and stops above 1.5 mm; the old gap-only trip (p < 1.5
mm) could not stop a 45 mm/s approach (rail contact, #11). The bound errs on the early side:
against the true plant (approaching at 50-100 mm/s at the hover current, 3-10 mm) it is up to 6.5x
the distance travelled (3.7x for a light plate with strong magnets, 9.6x for a 21.6 kg plate, whose
larger hover current the board reads as a stronger pull; measured after the 1/I widening), and up
to 15x at twice the hover current, where the neglected R i decays
the flux as fast as the bus does.

Lost sensor samples (a non-finite or missing gap or current)
-------------------------------------------------------------
One lost sample is not a fault: it is handled like a wild sample. A lost gap leaves that load
point's observer on its prediction (e = 0); a lost current is replaced by the board's coil model:
lambda+ = lambda + T (u - R_j i), i+ = lambda+ delta / (2K) (Eq. 5, delta from the observer; K
cancels between lambda and i), with R_j learned per coil while its current is measured (low-pass,
``R_LEARN_TIME``). Everything else (commands, limits, the braking check) runs unchanged.

Bound: ``SENSOR_BLIND_SAMPLES`` = 5 samples in a row per channel. Without a gap sample the
observer's error grows from the acceleration it misses, Da (n T)^2/2: with Da up to 10 m/s^2
(the plate's whole weight per kg) that is 0.125 mm after 5 ms, a quarter of INNOVATION_LIMIT
(so the returning sensor is taken, not set aside) and a twelfth of the braking check's margin
over rail contact; an unstable hover deviation grows by e every 17-20 ms, by 1.3x in 5 ms.

Beyond the bound:
* a *current* sensor: latched trip, brake-and-land with the coil model for that coil (the gaps
  close the loop; the bias b absorbs the model's force error). Measured: from an 8 mm hover
  with m, K, R off (tests), descent <= landing_speed, never toward the rail.
* a *gap* sensor j (the other gap and coil j's current still measured): latched trip, landing with
  gap j from coil j's flux. Decided on the first sample beyond the bound with gap k and current j both
  measured (|i_j| > FLUX_GAP_MIN_CURRENT): while either is only briefly blind (a spike, a dropped frame)
  the board rides on, as within the bound, and decides again each sample, at most 2 x SENSOR_BLIND_SAMPLES
  in all (any single run of <= SENSOR_BLIND_SAMPLES that touches the deciding sample has ended by then;
  the gap error grows to Da (2nT)^2/2 = 0.5 mm at most, INNOVATION_LIMIT; measured 11-14 um at hover after
  the full wait against 7-10 um without). FAULT at once when the flux landing is impossible for good: gap
  k or current j itself lost (blind beyond the bound), gap k already from its flux, |i_j| under the
  minimum; FAULT when the wait runs out. (Before: decided on one sample, so one NaN on gap k or current j
  there meant FAULT, 0 V at hover.) lambda_j starts at 2K i_j/delta_j with this sample's current (delta_j
  from the observer, which rode the blind samples) and is integrated from what the board applies and measures,
  lambda_j += T (u_j - R_j (i_j,prev + i_j)/2) with R_j as learned at hover (frozen from the loss);
  delta_j = 2K i_j / lambda_j, y_j = (delta_j - Q y_k) / P (K cancels against the start). That gap
  feeds the observer as a measurement; everything else runs unchanged. Its error is the integral of
  the R_j error times i: 0.02 ohm (0.07 % of a 28 ohm coil, what the learning reached in the test)
  at 5 A is 0.1 V s/s against 0.3 V s of flux, i.e. ~0.7 mm after 0.6 s. Measured (tests, 8 mm
  hover, 5 plant variants x 2 ends): peak descent 5.2-7.0 mm/s (landing_speed 10) with R nominal
  and m, K off by 25 %, 3 kg added; 11.2 mm/s with R 1.4x; never toward the rail; with R 0.75x the
  board declares LANDED with the lost end's true gap at 9.5-9.7 mm (then its current is removed:
  the rest is a fall of <= 1.7 mm onto the support, away from the rail); with R 1.4x it reads the plate
  resting on its support 1.7 mm short, the landing law lowers coil j's current under the minimum and the
  board FAULTs there (below). A sensor that reads again is taken again (flux re-anchored on it; without
  current j meanwhile, that coil runs on the coil model, as for a lost current sensor).
  The flux gap is a channel like the others: it counts as blind while it yields nothing (current j
  missing, |i_j| <= FLUX_GAP_MIN_CURRENT, gap k missing) and rides on the observer up to the bound;
  beyond it, before LANDED: FAULT (a current j lost is also seen on its own channel in the same sample).
  Landing on with no gap j and no current j is end j open loop on the coil model, the unstable plant:
  before this FAULT the board did so, and with gap j lost and then current j lost 20 ms into the landing
  the plate hit the rail 105-176 ms later in 8 of the 10 cases above (R 1.4x: landed). Likewise with
  |i_j| under the minimum the observer rode end j blind on a missed-acceleration estimate learned
  against the support (R 1.4x: the estimate ran through the rail, 651 braked samples and 200 V pulses
  on coil j for 0.8 s before LANDED). FAULT, 0 V (the flux gap's cases, and without the other gap or this
  coil's current or under FLUX_GAP_MIN_CURRENT at the decision): the plate drops onto its support, away
  from the rail (measured: never above its 8 mm hover, support impact 0.29-0.33 m/s from the first 20 ms
  of a landing).

A plausible but wrong gap reading (a stuck sensor)
--------------------------------------------------
A gap sensor frozen at a plausible value (in range, finite) passes every check above, and the controller and
the observer both steer by it: the unstable plate runs off the frozen reading (e every 17-20 ms) and, before
this check, reached the rail 183 ms after the freeze (the rig's stuck-sensor fault during S1's step). Only
physics the board measures independently can contradict it: each coil's flux. With lambda_j = 2K i_j/delta_j
and u_j = R_j i_j + d lambda_j/dt (Eq. 5), ``_GapCheck`` keeps per coil

    lam_j += T (u_j - r_j (i_j,prev + i_j)/2) + (T / FLUX_CHECK_TIME) (2K i_j/delta_j - lam_j)

(u: the voltage the bridges applied over the last period, ``step(applied=...)`` where the board measures it;
r_j: the coil model's resistance, followed over FLUX_CHECK_R_TIME and only while the differences below are
small: the coil model's own R follows a wrong reading within R_LEARN_TIME). At hover the flux is 2 sqrt(K F),
the same at every gap, so a plate moving under its weight changes it little: the magnet gaps from the fluxes,
2K i_j/lam_j, back to sensor gaps (the inverse of [[P, Q], [Q, P]]), follow the true plate for ~FLUX_CHECK_TIME
while the readings follow the sensors. Per sensor the difference reading - flux gap, low-passed
(FLUX_CHECK_FILTER), is checked against

    tolerance = FLUX_CHECK_MIN + e/(1 - e) |flux change over FLUX_CHECK_TIME| (as a gap) + FLUX_CHECK_SIGMAS sigma

(e = BOUND_MARGIN: a magnet that far off its datasheet K scales the measured flux change; sigma: the
difference's own RMS, bias included, learned over FLUX_CHECK_NOISE_TIME while it is under half the
tolerance: a slow drift such as a heating coil widens it, a difference growing within ~10 ms does not). The
check arms FLUX_CHECK_ARM after its start (RUN), once both differences stayed under FLUX_CHECK_MIN / 3 for
FLUX_CHECK_SETTLE samples, and restarts with every RUN and on a non-finite or non-positive flux estimate.
FLUX_CHECK_SAMPLES samples beyond the tolerance (samples without a reading to compare do not reset the count)
declare the sensor implausible: ``implausible[j]`` latches (status bit GAPj_IMPLAUSIBLE on the device link),
its readings are ignored until ``clear()``, the observer restarts that end at the flux gap and its rate, and
the board lands on coil j's flux as for a lost sensor (below), the flux starting at the check's estimate.
During that landing (or one for a lost sensor) the other sensor stays checked, against the flux gap and its
own coil's flux. Both sensors beyond the tolerance, at once or one after the other: FAULT (0 V, no gap left;
the plate falls away from the rail whatever the sensors read: safe under both explanations, two frozen
sensors, or a fault on the voltage side that offsets both). The board measures the voltage its coils get
(``step(applied=...)``: the rig board its bridges' output after the scenario's input perturbation,
``plant_sim``'s the same), so a failed coil driver is not taken for a sensor; a wrong voltage reading is:
one 0 V sample on coil 1 at hover (review) offsets both differences at once, FAULT.

Measured (tests/hardware/test_rig.py, the rig board in lockstep with the graph's estimator and controller,
S1, gap j frozen 1.5 s after its step): found 0.55 mm off, the plate's closest approach 6.1 mm (gap 1) and
its descent 8.6 mm/s; tests/core/test_safety.py: frozen at 8 mm, pushed toward or away from the rail at
1 cm/s, m, R, K off by 25 % and 3 kg added: found, landed, never near the rail; healthy sensors never found
implausible across that grid, the landing grid and S3c's noise; both frozen: FAULT with the plate 5.6 mm or
more from the rail. Limits: a sensor stuck while the plate holds still is not seen (nor harmful until it
moves); the complementary filter absorbs differences slower than ~FLUX_CHECK_TIME, so a sensor that drifts
or offsets slowly is not seen either (the estimator's innovation and bias checks are what remain); a
voltage on the coils the board does not measure (as S4b's 20 V at 50 Hz before the boards measured it) is
taken for a sensor fault; the flux landing carries the magnet's K error (K 0.75 and 3 kg added, falling
away: the flux read the plate on its support as 6.7 mm, the board FAULTed there once coil j's current fell
under FLUX_GAP_MIN_CURRENT). Cost: Supervisor.step 9 -> 13 us per sample at hover (pure Python on plain floats;
measured 2026-11-26 01:20 UTC, load ~1; 25 us with numpy on 2-vectors).

The landing law (uses only what a board has: measured gaps y (2,) [m] and coil
currents i (2,) [A], nominal parameters m, R, K, L, l, I, N1, N2, g)
-----------------------------------------------------------------------------
Per load point j, the model acceleration at the measured currents (Eqs. 3-8)::

    delta = [P y1 + Q y2, Q y1 + P y2]          F_j = K i_j^2 / delta_j^2
    a_m   = n - M F,   M = [[A, B], [B, A]],   n = [C N1 + D N2 + g, D N1 + C N2 + g]

1. *Observer* (runs in every mode, so LAND starts from converged estimates): per load
   point the states ``s = [p, v, b]`` (gap [m], gap rate [m/s], acceleration the
   nominal model misses [m/s^2]: mass, K, R errors, added load)::

       predict:  p- = p + T v + T^2/2 (a_m + b),  v- = v + T (a_m + b),  b- = b
       correct:  s  = s- + Lo (y - p-)    (one sample with |y - p-| > INNOVATION_LIMIT: s = s-)

   ``Lo`` (3,) places the error poles of (I - Lo C) A at exp(-w_obs T) (double,
   ``OBS_BANDWIDTH``) and exp(-w_b T) (``BIAS_BANDWIDTH``, slower: b is a second
   derivative of the sensor noise); b makes v unbiased under constant model errors
   and is the disturbance the outer loop cancels. At LAND entry b already holds
   the hover's model error, so the transfer is bumpless. The prediction misses the
   true motion by the unmodelled acceleration times T^2/2 (micrometres), so an
   innovation above 0.5 mm is a wild sample: one such sample alone is set aside (it must
   not fake a 190 mm/s approach, which the braking check would act on); a second in a
   row is real (a step: the plate hit its support, or moves faster than the model knows) and
   restarts gap and rate from the two samples (p = y_k, v = (y_k - y_k-1)/T; b kept). Passing
   it through Lo instead left the rate 290 mm/s wrong after a plate hit its support at speed,
   and the landing law then pulled that end back up toward the rail (measured: 0.67 mm, the
   light-plate/strong-magnet rogue command from 8 mm; 3.65 mm with the restart).
2. *Reference*: from the estimate at LAND entry (a rising plate's reference first decelerates at
   |r'| / CAPTURE_TIME, at most CAPTURE_ACCEL, so the loop does not pull it back against its own momentum:
   that made a plate caught rising at 50 mm/s descend at 15 mm/s), r_j accelerates at ``REF_ACCEL`` to
   ``v_ref = SPEED_FRACTION * landing_speed`` (down, away from the rail) and stops
   ``LANDING_OVERSHOOT`` beyond ``landing_gap`` (each load point: a tilted plate
   levels on the way); it starts with the plate's own downward speed (clipped to
   [0, v_ref]). SPEED_FRACTION = 0.4 leaves the rest of the bound to the motion the
   sensor noise drives through the loop (measured: tests).
3. *Outer loop* (disturbance-observer feedback linearisation)::

       a*_j = r''_j + kd (r'_j - v_j) + kp (r_j - p_j),   kp = w^2, kd = 2 w  (w = OUTER_BANDWIDTH)
       F*   = M^-1 (n - a*_j + b),  clipped to [0, K i_lim^2/delta^2]     (attraction only)
       i*_j = delta_j sqrt(F*_j / K)

4. *Current loop* (inverts u = R i + d(2K i/delta)/dt)::

       u_j = R i_j + ui_j + (2K/delta_j) (kc (i*_j - i_j) - i_j delta_j'/delta_j),   kc = CURRENT_BANDWIDTH
       ui_j += T (kc^2/5) (2K/delta_j) (i*_j - i_j)     (integral: the R error; frozen while saturated)

   clipped to ``u_max``; ui starts at (last applied voltage - R i) so the voltage does not jump. The plate reaches its support (min(p) >= landing_gap) at
   about v_ref; LANDED then drives the currents to zero with the same loop (i* = 0).

With w = 30 rad/s, w_obs = 150 rad/s, w_b = 30 rad/s, kc = 500 /s at T = 1 ms, the law lands from
hovers at 4-10 mm, tilted, with m, R, K off by +-25 %, 3 kg added and measurement
noise (+-30 um, +-0.3 mA), descending at <= landing_speed and never closer to the rail
than it started (tests/core/test_safety.py); with +-100 um gap noise the noise-driven
motion takes the peak descent speed to 0.94-1.17 landing_speed (measured; tested <= 1.5).
It needs the bus to hold the plate near ``landing_gap``: R i <= u_max with
i = (landing_gap + LANDING_OVERSHOOT) sqrt((N + m g/2)/K) (nominal: 113 V at 11.3 mm;
the 200 V default covers m +25 % and +3 kg, R +25 %, K -25 % all at once: 186 V).

Names refined from PLAN.md: the gap trips are ``trip_gap_min``/``trip_gap_max`` (the
plant_sim group already has ``gap_min``/``gap_max``: the plant's failure limits);
``Supervisor(cfg, dt, mode=Mode.OFF, u0=None)``; attributes ``fault`` (latched reason),
``u`` and ``estimate`` and method ``snapshot()`` are additions.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numba import njit

__all__ = [
    "BIAS_BANDWIDTH",
    "BOUND_MARGIN",
    "CURRENT_BANDWIDTH",
    "INNOVATION_LIMIT",
    "LANDING_OVERSHOOT",
    "OBS_BANDWIDTH",
    "OUTER_BANDWIDTH",
    "PLANT_KEYS",
    "REF_ACCEL",
    "SAFETY_KEYS",
    "SENSOR_BLIND_SAMPLES",
    "SPEED_FRACTION",
    "Mode",
    "SafetyError",
    "Supervisor",
    "observer_gains",
]

#: the safety specs (core/params.py ``SAFETY_SPECS``) a Supervisor reads from its cfg
SAFETY_KEYS = ("u_max", "i_max", "trip_gap_min", "trip_gap_max", "hold_timeout", "landing_gap", "landing_speed")
#: nominal plant parameters a Supervisor reads from its cfg
PLANT_KEYS = ("m", "R", "K", "L", "l", "I", "N1", "N2", "g")

OUTER_BANDWIDTH = 30.0  # rad/s, w of the landing law's gap loop
OBS_BANDWIDTH = 150.0  # rad/s, observer error poles of gap and rate at exp(-w_obs T)
BIAS_BANDWIDTH = 30.0  # rad/s, observer error pole of the missed acceleration (slower: less noise)
CURRENT_BANDWIDTH = 500.0  # 1/s, current loop gain kc (kc T = 0.5: fast against the plate, slow against the sample)
SPEED_FRACTION = 0.4  # the reference descends at this fraction of landing_speed (margin for noise)
REF_ACCEL = 0.2  # m/s^2, the reference's acceleration to v_ref
CAPTURE_ACCEL = 5.0  # m/s^2, the reference's largest deceleration of a plate rising when the landing starts
CAPTURE_TIME = 0.01  # s: it decelerates a rising plate's speed v at |v| / CAPTURE_TIME (at least REF_ACCEL)
LANDING_OVERSHOOT = 3e-4  # m: the reference stops this far beyond landing_gap (the support)
I_OFF = 0.02  # A: below this, LANDED applies 0 V
BOUND_MARGIN = 0.25  # the braking bound's model margin e: K, 1/m, 1/I each within a factor 1 -+ e
INNOVATION_LIMIT = 5e-4  # m: a single sample this far off the observer's prediction is set aside as wild
R_LEARN_TIME = 0.05  # s: the coil model learns each coil's resistance with this time constant
SENSOR_BLIND_SAMPLES = 5  # samples a gap/current channel may give nothing finite before the board lands
FLUX_GAP_MIN_CURRENT = 0.5  # A: below this a coil's flux tells too little of its gap (a lost gap sensor: FAULT)
_SENSOR_NAMES = ("gap sensor 1", "gap sensor 2", "current sensor 1", "current sensor 2")
# the gap sensors' plausibility against the coils' fluxes (module docstring, "A plausible but wrong gap reading")
FLUX_CHECK_TIME = 0.05  # s: the flux estimate follows the measured flux 2K i/delta with this time constant
FLUX_CHECK_R_TIME = 0.2  # s: its coil resistance follows the coil model's (R_LEARN_TIME) this slowly, and only
#                            while the differences are small (the coil model's follows a wrong reading in 50 ms)
FLUX_CHECK_ARM = 0.3  # s: valid samples before a coil's check counts (the flux estimate settles)
FLUX_CHECK_FILTER = 0.003  # s: low-pass of the gap differences
FLUX_CHECK_NOISE_TIME = 1.0  # s: the differences' noise level is learned over this time
FLUX_CHECK_MIN = 3e-4  # m: the smallest difference that counts
FLUX_CHECK_SIGMAS = 6.0  # the tolerance is at least this many times the learned noise level
FLUX_CHECK_SETTLE = 50  # samples: the check arms after this many in a row with both differences small
FLUX_CHECK_SAMPLES = 3  # samples in a row beyond the tolerance declare the sensor implausible


class Mode(enum.IntEnum):
    """Board mode; the values are the device link's mode byte (``dem_ros.hardware.link`` imports this)."""

    OFF = 0  # no current in the coils (plate resting on its support, or not started)
    RUN = 1  # applying the commanded voltages, clipped to u_max
    HOLD = 2  # a command is late: the last one is held, at most hold_timeout
    LAND = 3  # the landing law lowers the plate away from the rail at <= landing_speed (also after a trip or e-stop)
    LANDED = 4  # on the support at landing_gap, current removed
    FAULT = 5  # a non-finite gap or current: nothing left to control with, 0 V (latched)


class SafetyError(ValueError):
    """An invalid supervisor configuration; the message names the field."""


def observer_gains(T: float, w: float, w_bias: float) -> np.ndarray:
    """Lo (3,) of the current-estimator form: the eigenvalues of (I - Lo C) A are exp(-w T) (double)
    and exp(-w_bias T) (the missed-acceleration estimate, slower: it is a second derivative of noise).

    A = [[1, T, T^2/2], [0, 1, T], [0, 0, 1]], C = [1, 0, 0]. Ackermann on the pair
    (A, C A): Lo = phi(A) [CA; CA^2; CA^3]^-1 e3, phi(z) = (z - exp(-w T))^2 (z - exp(-w_bias T)).
    """
    A = np.array([[1.0, T, T * T / 2], [0.0, 1.0, T], [0.0, 0.0, 1.0]])
    C = np.array([[1.0, 0.0, 0.0]])
    lam = math.exp(-w * T)
    lam_b = math.exp(-w_bias * T)
    eye = np.eye(3)
    phi = (A - lam * eye) @ (A - lam * eye) @ (A - lam_b * eye)
    O = np.vstack([C @ A, C @ A @ A, C @ A @ A @ A])
    return (phi @ np.linalg.solve(O, np.array([0.0, 0.0, 1.0]))).ravel()


# kernel parameter vector
_P, _Q, _A, _B, _C, _D, _K, _R, _N1, _N2, _G, _T, _KP, _KD, _KC, _UMAX, _ILIM, _DMIN, _VREF, _AREF, _RSTOP, _KI = range(22)
_KB, _AB, _BB, _NB1, _NB2 = range(22, 27)  # the braking bound's widened model (module docstring)
_EMAX = 27  # observer innovation limit [m]
_KBL = 28  # the braking bound's weakest magnet (1 - e) K
_ACAP = 29  # the landing reference's largest deceleration of a rising plate [m/s^2]
_TCAP = 30  # ... at |r'| / CAPTURE_TIME [s]
_NP = 31


@njit(cache=True)
def _model_accel(p: np.ndarray, de1: float, de2: float, i1: float, i2: float, a: np.ndarray) -> None:
    """a = n - M F at gaps delta and currents i (nominal model)."""
    F1 = p[_K] * i1 * i1 / (de1 * de1)
    F2 = p[_K] * i2 * i2 / (de2 * de2)
    a[0] = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - p[_A] * F1 - p[_B] * F2
    a[1] = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - p[_B] * F1 - p[_A] * F2


@njit(cache=True)
def _deltas(p: np.ndarray, y1: float, y2: float) -> tuple[float, float]:
    de1 = max(p[_P] * y1 + p[_Q] * y2, p[_DMIN])
    de2 = max(p[_Q] * y1 + p[_P] * y2, p[_DMIN])
    return de1, de2


@njit(cache=True)
def _observe(p: np.ndarray, Lo: np.ndarray, s: np.ndarray, a: np.ndarray, y0: float, y1: float, i0: float,
             i1: float, gated: np.ndarray, blind: np.ndarray, wild: np.ndarray) -> None:
    """One observer step. s (3, 2): [p, v, b] per load point; a (2,): model acceleration of the last step (updated);
    gated (2,): per load point, 1 when the last sample was set aside as wild (updated), wild (2,) that sample [m];
    blind (2,): 1 where
    there is no gap sample (non-finite or missing): prediction only, like a wild sample."""
    T = p[_T]
    for j in range(2):
        acc = a[j] + s[2, j]
        pp = s[0, j] + T * s[1, j] + 0.5 * T * T * acc
        vp = s[1, j] + T * acc
        # no sample: the prediction alone (the wild-sample gate keeps its state)
        e = 0.0 if blind[j] != 0.0 else (y0 if j == 0 else y1) - pp
        if blind[j] != 0.0:
            pass
        elif abs(e) > p[_EMAX] and gated[j] == 0.0:
            gated[j] = 1.0  # one wild sample is set aside (prediction only); a second in a row is real
            wild[j] = pp + e
            e = 0.0
        elif abs(e) > p[_EMAX]:
            # two in a row: a real step (the plate hit its support, or moved faster than the model knows):
            # restart gap and rate from the two samples; the missed acceleration is kept
            gated[j] = 0.0
            y = pp + e
            s[0, j] = y
            s[1, j] = (y - wild[j]) / T
            continue
        else:
            gated[j] = 0.0
        s[0, j] = pp + Lo[0] * e
        s[1, j] = vp + Lo[1] * e
        s[2, j] = s[2, j] + Lo[2] * e
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    _model_accel(p, de1, de2, i0, i1, a)


@njit(cache=True)
def _land_law(p: np.ndarray, s: np.ndarray, ref: np.ndarray, ui: np.ndarray, i: np.ndarray, landed: bool,
              u: np.ndarray) -> None:
    """Voltages u (2,) of the landing law.

    ref (3, 2) = [r, r', r''] per load point and ui (2,) the current loop's integral [V] are advanced here.
    """
    T = p[_T]
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    dd1 = p[_P] * s[1, 0] + p[_Q] * s[1, 1]
    dd2 = p[_Q] * s[1, 0] + p[_P] * s[1, 1]
    istar1 = 0.0
    istar2 = 0.0
    if not landed:
        a1 = ref[2, 0] + p[_KD] * (ref[1, 0] - s[1, 0]) + p[_KP] * (ref[0, 0] - s[0, 0])
        a2 = ref[2, 1] + p[_KD] * (ref[1, 1] - s[1, 1]) + p[_KP] * (ref[0, 1] - s[0, 1])
        h1 = p[_C] * p[_N1] + p[_D] * p[_N2] + p[_G] - a1 + s[2, 0]  # M F* = n - a* + b
        h2 = p[_D] * p[_N1] + p[_C] * p[_N2] + p[_G] - a2 + s[2, 1]
        det = p[_A] * p[_A] - p[_B] * p[_B]
        F1 = (p[_A] * h1 - p[_B] * h2) / det
        F2 = (-p[_B] * h1 + p[_A] * h2) / det
        F1 = min(max(F1, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de1 * de1))
        F2 = min(max(F2, 0.0), p[_K] * p[_ILIM] * p[_ILIM] / (de2 * de2))
        istar1 = de1 * math.sqrt(F1 / p[_K])
        istar2 = de2 * math.sqrt(F2 / p[_K])
        # the reference stops a rising plate (r'' = a_cap while r' < 0), descends (r'' = a_ref up to
        # r' = v_ref) and stops at r_stop
        for j in range(2):
            ref[0, j] += T * ref[1, j] + 0.5 * T * T * ref[2, j]
            ref[1, j] += T * ref[2, j]
            if ref[1, j] < 0.0:
                ref[2, j] = min(max(-ref[1, j] / p[_TCAP], p[_AREF]), p[_ACAP])
            elif ref[1, j] >= p[_VREF]:
                ref[1, j] = p[_VREF]
                ref[2, j] = 0.0
            else:
                ref[2, j] = p[_AREF]
            if ref[0, j] >= p[_RSTOP]:
                ref[0, j] = p[_RSTOP]
                ref[1, j] = 0.0
                ref[2, j] = 0.0
    else:
        ui[0] = 0.0
        ui[1] = 0.0
    kK = 2.0 * p[_K]
    e1 = istar1 - i[0]
    e2 = istar2 - i[1]
    u[0] = p[_R] * i[0] + ui[0] + kK / de1 * (p[_KC] * e1 - i[0] * dd1 / de1)
    u[1] = p[_R] * i[1] + ui[1] + kK / de2 * (p[_KC] * e2 - i[1] * dd2 / de2)
    for j in range(2):
        lim = p[_UMAX]
        if u[j] > lim:
            u[j] = lim
        elif u[j] < -lim:
            u[j] = -lim
        elif not landed:  # integrate only when not saturated (anti-windup)
            e = e1 if j == 0 else e2
            de = de1 if j == 0 else de2
            ui[j] += T * p[_KI] * kK / de * e


@njit(cache=True)
def _force_bound(p: np.ndarray, i: float, de: float, uc: float) -> tuple[float, float]:
    """(F+ [N], lambda+ [V s]) of one magnet after one sample of uc [V] from current i [A] at gap delta [m]:
    the largest force over K in [(1 - e) K, (1 + e) K] and the largest flux (at (1 + e) K).

    F+(K) = (K a + c)^2 / (4 K), a = 2|i|/delta, c = T|uc|, is convex in K (F+'' = c^2 / (2 K^3) >= 0): its
    maximum over an interval is at an end (the stationary point K = c/a is the minimum), so both ends."""
    a = 2.0 * abs(i) / de
    c = p[_T] * abs(uc)
    hi = p[_KB] * a + c
    lo = p[_KBL] * a + c
    return max(hi * hi / (4.0 * p[_KB]), lo * lo / (4.0 * p[_KBL])), hi


@njit(cache=True)
def _stop_gaps(p: np.ndarray, s: np.ndarray, i: np.ndarray, uc: np.ndarray, U: float, out: np.ndarray) -> None:
    """Predicted stopping gaps out (2,) [m]: candidate uc (2,) [V] for one sample, then brake at U [V].

    s (3, 2): observer state; i (2,): measured currents [A]. The bound of the module docstring.
    """
    T = p[_T]
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    F1, lam1 = _force_bound(p, i[0], de1, uc[0])
    F2, lam2 = _force_bound(p, i[1], de2, uc[1])
    for j in range(2):
        Fj, Fk = (F1, F2) if j == 0 else (F2, F1)
        lj, lk = (lam1, lam2) if j == 0 else (lam2, lam1)
        n = p[_NB1] if j == 0 else p[_NB2]
        G = p[_AB] * Fj + p[_BB] * Fk
        lam = max(lj, lk) if p[_BB] > 0.0 else lj
        tau = lam / U + T
        w = -s[1, j]
        a0 = G - n
        s0 = max(w, 0.0) * T + max(a0, 0.0) * 0.5 * T * T
        w1 = w + a0 * T + G * tau / 3.0
        D = s0 + (w1 * w1 / (2.0 * n) if w1 > 0.0 else 0.0)
        out[j] = s[0, j] - D


@njit(cache=True)
def _brake(p: np.ndarray, s: np.ndarray, i: np.ndarray, U: float, u: np.ndarray) -> None:
    """The brake u (2,) [V]: each coil's current to zero in one sample (u = R i - (2K/delta) i/T), clipped to +-U."""
    de1, de2 = _deltas(p, s[0, 0], s[0, 1])
    for j in range(2):
        de = de1 if j == 0 else de2
        v = p[_R] * i[j] - 2.0 * p[_K] / de * i[j] / p[_T]
        u[j] = min(max(v, -U), U)



class _GapCheck:
    """The gap sensors' plausibility against the coils' fluxes (module docstring, "A plausible but wrong gap
    reading"). Per coil j a flux estimate integrated from the voltage applied, lam_j += T (u_j - R_j i_j), pulled
    toward the measured flux 2K i_j / delta_j (delta from the two gap readings) with FLUX_CHECK_TIME; per gap
    sensor the difference between its reading and the gap the two flux estimates give, low-passed, against a
    tolerance: FLUX_CHECK_MIN, plus what a magnet BOUND_MARGIN off its datasheet K explains of the recent flux
    change, plus FLUX_CHECK_SIGMAS times the difference's own noise level (learned while within tolerance)."""

    def __init__(self, p: np.ndarray, dt: float):
        # plain floats: the 1 kHz path does 2 x 2 arithmetic, where numpy's per-call overhead is most of the cost
        self.dt, self.K2, self.P, self.Q = float(dt), 2.0 * float(p[_K]), float(p[_P]), float(p[_Q])
        inv = np.linalg.inv(np.array([[self.P, self.Q], [self.Q, self.P]]))  # magnet gaps -> sensor gaps
        self.m_inv = ((float(inv[0, 0]), float(inv[0, 1])), (float(inv[1, 0]), float(inv[1, 1])))
        self.k_margin = BOUND_MARGIN / (1.0 - BOUND_MARGIN)  # flux change a magnet off by BOUND_MARGIN hides
        self.n_arm = round(FLUX_CHECK_ARM / dt)
        self.reset()

    def reset(self) -> None:
        self.n = [0, 0]  # samples each coil's flux estimate has been corrected (0: not started)
        # per coil / per sensor, plain lists of floats (the 1 kHz path: numpy's per-element overhead is not worth it)
        self.lam = [0.0, 0.0]  # flux estimates [V s]
        self.lam_lp = [0.0, 0.0]  # the measured flux, low-passed like the estimate's correction [V s]
        self.r = [0.0, 0.0]  # the resistance the estimate integrates with [ohm]
        self.i_prev = [0.0, 0.0]
        self.dy = [0.0, 0.0]  # sensor reading - flux gap, low-passed [m]
        self.var = [0.0, 0.0]  # its noise level [m^2]
        self.tol = [math.inf, math.inf]  # the last tolerance [m]
        self.over = [0, 0]  # samples in a row beyond it
        self.armed = False  # settled: FLUX_CHECK_ARM of samples, then both differences within FLUX_CHECK_MIN / 3
        self.settled = 0  # for this many samples in a row (arming takes FLUX_CHECK_SETTLE of them)
        self.sum_sq = [0.0, 0.0]  # their squares meanwhile: the first noise level [m^2]
        self.calm = True  # both differences within half their tolerance at the last sample
        self.y_flux = [math.nan, math.nan]  # the gaps the flux estimates give [m]
        self.v_flux = [0.0, 0.0]  # their rates, low-passed [m/s]

    def restart_sensor(self, n: int) -> None:
        """Sensor n was given up (its gap now comes from coil n's flux): its difference starts again at zero,
        the other sensor stays checked against both coils' fluxes."""
        self.dy[n] = 0.0
        self.over = [0, 0]

    def step(self, y0: float, y1: float, i: tuple[float, float], i_ok: tuple[bool, bool], u: np.ndarray,
             r_model: np.ndarray, given_up: tuple[bool, bool] = (False, False)) -> int:
        """One sample: gaps (NaN: none), currents i (2,) [A] (the coil model's where i_ok is False), the voltages
        applied over the last period u (2,) [V], the coil model's resistances; ``given_up``: sensors whose gap
        is already their coil's flux gap (never declared again). Returns the gap sensor newly found implausible
        (0, 1), 2 for both at once, -1 for none."""
        T, K2, P, Q = self.dt, self.K2, self.P, self.Q
        gaps = math.isfinite(y0) and math.isfinite(y1)
        de = (P * y0 + Q * y1, Q * y0 + P * y1) if gaps else (math.nan, math.nan)
        lam_m = [math.nan, math.nan]
        for j in (0, 1):
            measured = gaps and i_ok[j] and abs(i[j]) > FLUX_GAP_MIN_CURRENT and de[j] > 0.0
            if measured:
                lam_m[j] = K2 * i[j] / de[j]
            if self.n[j] == 0:
                if measured:
                    self.lam[j] = self.lam_lp[j] = lam_m[j]
                    self.r[j] = float(r_model[j])
                    self.i_prev[j] = i[j]
                    self.n[j] = 1
                continue
            self.lam[j] += T * (float(u[j]) - self.r[j] * 0.5 * (self.i_prev[j] + i[j]))
            self.i_prev[j] = i[j]
            if measured:
                a = T / FLUX_CHECK_TIME
                self.lam[j] += a * (lam_m[j] - self.lam[j])
                self.lam_lp[j] += a * (lam_m[j] - self.lam_lp[j])
                self.n[j] += 1
            if not self.armed:
                self.r[j] = float(r_model[j])  # settling: follow the coil model's resistance
            elif self.calm:
                self.r[j] += T / FLUX_CHECK_R_TIME * (float(r_model[j]) - self.r[j])
        if not (math.isfinite(self.lam[0]) and math.isfinite(self.lam[1])) or min(self.lam[0], self.lam[1]) <= 0.0:
            self.reset()  # a non-finite voltage or current, or a flux through zero: start again
            return -1
        if not (math.isfinite(lam_m[0]) and math.isfinite(lam_m[1])) or min(self.n) == 0:
            return -1  # no sample to compare: the counts of samples beyond the tolerance wait for the next
        d0, d1 = K2 * i[0] / self.lam[0], K2 * i[1] / self.lam[1]  # the fluxes' magnet gaps
        (m00, m01), (m10, m11) = self.m_inv
        y_flux = (m00 * d0 + m01 * d1, m10 * d0 + m11 * d1)
        b = T / FLUX_CHECK_FILTER
        for s in (0, 1):
            if math.isfinite(self.y_flux[s]):
                self.v_flux[s] += b * ((y_flux[s] - self.y_flux[s]) / T - self.v_flux[s])
            self.y_flux[s] = y_flux[s]
        allow = [self.k_margin * abs((lam_m[j] - self.lam_lp[j]) / lam_m[j]) * de[j] for j in (0, 1)]
        armed = self.armed
        v = T / FLUX_CHECK_NOISE_TIME
        for s, ys in ((0, y0), (1, y1)):
            self.dy[s] += b * ((ys - self.y_flux[s]) - self.dy[s])
        if not armed:
            if min(self.n) > self.n_arm and max(abs(self.dy[0]), abs(self.dy[1])) < FLUX_CHECK_MIN / 3.0:
                self.settled += 1
                self.sum_sq = [self.sum_sq[0] + self.dy[0] ** 2, self.sum_sq[1] + self.dy[1] ** 2]
                if self.settled >= FLUX_CHECK_SETTLE:
                    self.armed = True
                    self.var = [self.sum_sq[0] / self.settled, self.sum_sq[1] / self.settled]
            else:
                self.settled = 0
                self.sum_sq = [0.0, 0.0]
            return -1
        calm = True
        for s in (0, 1):
            if given_up[s]:
                self.over[s] = 0
                continue
            row = self.m_inv[s]
            self.tol[s] = (FLUX_CHECK_MIN + abs(row[0]) * allow[0] + abs(row[1]) * allow[1]
                           + FLUX_CHECK_SIGMAS * math.sqrt(self.var[s]))
            if abs(self.dy[s]) > self.tol[s]:
                self.over[s] += 1
                calm = False
                continue
            self.over[s] = 0
            if abs(self.dy[s]) < 0.5 * self.tol[s]:  # the noise level, not a growing difference
                self.var[s] += v * (self.dy[s] ** 2 - self.var[s])
            else:
                calm = False
        self.calm = calm
        bad = [s for s in (0, 1) if self.over[s] >= FLUX_CHECK_SAMPLES]
        if not bad:
            return -1
        if len(bad) == 2 or self.over[1 - bad[0]] > 0:
            return 2
        return bad[0]


class Supervisor:
    """The board: hard limits, command watchdog, landing law (see the module docstring).

    Args:
        cfg: the safety specs (``SAFETY_KEYS``, SI units) and the nominal plant
            parameters (``PLANT_KEYS``); extra keys are ignored.
        dt: sample period T [s].
        mode: the mode to start in; ``Mode.RUN`` when the plate already hovers
            under a voltage given as ``u0`` (2,) [V] (the simulator's initial hover).

    Attributes:
        mode: current :class:`Mode`.
        reason: why the supervisor is in this mode ("" in OFF/RUN).
        fault: the latched fault reason ("" when none), cleared by ``clear()``.
        counters: sample and event counts (see the module docstring).
        u (2,): the voltages applied by the last ``step`` [V] (the array ``step`` returned;
            the board may return it again, never changes it in place).
        estimate (3, 2): observer state [gap m, rate m/s, missed acceleration m/s^2] per load point.
        stop_gap (2,): the last predicted stopping gap per load point [m] (the braking bound).
        min_stop_gap: the smallest predicted stopping gap checked so far [m].
        implausible (2,): gap sensor j found contradicting the coils' fluxes (latched until ``clear()``;
            the board's status bits GAPj_IMPLAUSIBLE).
        command_timeout: the landing was started by ``hold_timeout`` without a command (the board's link
            watchdog: status bit LINK_TIMEOUT), until ``clear()``.
    """

    def __init__(self, cfg: Mapping[str, Any], dt: float, mode: Mode = Mode.OFF, u0: np.ndarray | None = None):
        missing = [k for k in SAFETY_KEYS + PLANT_KEYS if k not in cfg]
        if missing:
            raise SafetyError(f"supervisor configuration lacks {missing}")
        try:
            c = {k: float(cfg[k]) for k in SAFETY_KEYS + PLANT_KEYS}
        except (TypeError, ValueError):
            bad = {k: cfg[k] for k in SAFETY_KEYS + PLANT_KEYS if not isinstance(cfg[k], (int, float))}
            raise SafetyError(f"supervisor configuration: not numbers: {bad}") from None
        for k in ("u_max", "i_max", "hold_timeout", "landing_gap", "landing_speed", "m", "R", "K", "L", "l", "I"):
            if not (math.isfinite(c[k]) and c[k] > 0):
                raise SafetyError(f"{k} = {c[k]!r} must be a positive finite number")
        if not 0 <= c["trip_gap_min"] < c["landing_gap"] <= c["trip_gap_max"]:
            raise SafetyError(
                f"need 0 <= trip_gap_min < landing_gap <= trip_gap_max; got {c['trip_gap_min']:g}, "
                f"{c['landing_gap']:g}, {c['trip_gap_max']:g} m")
        if not c["l"] < c["L"]:
            raise SafetyError(f"l = {c['l']:g} m must be smaller than L = {c['L']:g} m")
        if not (math.isfinite(dt) and dt > 0):
            raise SafetyError(f"dt = {dt!r} must be a positive finite number [s]")
        self.cfg = c
        self.dt = float(dt)
        L, l, m, In = c["L"], c["l"], c["m"], c["I"]
        p = np.zeros(_NP)
        p[_P] = (L + l) / (2 * L)
        p[_Q] = (L - l) / (2 * L)
        p[_A] = 1 / m + L * l / In
        p[_B] = 1 / m - L * l / In
        p[_C] = 1 / m + L * L / In
        p[_D] = 1 / m - L * L / In
        p[_K], p[_R], p[_N1], p[_N2], p[_G] = c["K"], c["R"], c["N1"], c["N2"], c["g"]
        p[_T] = self.dt
        p[_KP] = OUTER_BANDWIDTH**2
        p[_KD] = 2.0 * OUTER_BANDWIDTH
        p[_KC] = CURRENT_BANDWIDTH
        p[_UMAX] = c["u_max"]
        p[_ILIM] = 0.95 * c["i_max"]
        p[_DMIN] = 1e-4
        p[_VREF] = SPEED_FRACTION * c["landing_speed"]
        p[_AREF] = REF_ACCEL
        p[_ACAP] = CAPTURE_ACCEL
        p[_TCAP] = CAPTURE_TIME
        p[_RSTOP] = c["landing_gap"] + LANDING_OVERSHOOT
        p[_KI] = CURRENT_BANDWIDTH**2 / 5.0
        e = BOUND_MARGIN
        p[_EMAX] = INNOVATION_LIMIT
        p[_KB] = (1 + e) * c["K"]
        p[_KBL] = (1 - e) * c["K"]
        p[_AB] = (1 + e) * (1 / m + L * l / In)
        p[_BB] = max((1 + e) / m - (1 - e) * L * l / In, 0.0)
        p[_NB1] = c["g"] + min(0.0, (1 + e) * L * L / In * (c["N1"] - c["N2"]))
        p[_NB2] = c["g"] + min(0.0, (1 + e) * L * L / In * (c["N2"] - c["N1"]))
        if not min(p[_NB1], p[_NB2]) > 0:
            raise SafetyError(f"no braking away from the rail: with N1 = {c['N1']:g} N, N2 = {c['N2']:g} N the pull "
                              f"away from the rail at the ends is {p[_NB1]:.3g}, {p[_NB2]:.3g} m/s^2 (must be > 0)")
        self._p = p
        self._Lo = observer_gains(self.dt, OBS_BANDWIDTH, BIAS_BANDWIDTH)
        self._u_max = c["u_max"]
        self._i_max = c["i_max"]
        self._hold_ns = round(c["hold_timeout"] * 1e9)
        self.estimate = np.zeros((3, 2))
        self._acc = np.zeros(2)
        self._i_last = (0.0, 0.0)
        self._ref = np.zeros((3, 2))
        self._ui = np.zeros(2)
        self._obs_ready = False
        self.u = np.zeros(2) if u0 is None else np.asarray(u0, float).copy()
        self._u_last: np.ndarray = self.u.copy()
        self._t_fresh: int | None = None
        self._braking = False
        self._gated = np.zeros(2)
        self._wild = np.zeros(2)
        self._blind = [0, 0, 0, 0]  # consecutive samples without a finite gap 1, gap 2, current 1, current 2
        self._blind_now = np.zeros(2)
        self._i_est = np.zeros(2)  # the coil model's current for the next sample [A]
        self._lam = np.zeros(2)  # the coil model's flux linkage 2K i/delta [V s]
        self._r_est = np.full(2, c["R"])
        self._lam_pred = np.zeros(2)
        self._u_prev = np.zeros(2)  # each coil's resistance, learned while its current is measured [ohm]
        self._flux_gap = [False, False]  # gap sensor j given up: its gap from coil j's flux (_gaps_from_flux)
        self._lam_flux = np.zeros(2)  # that coil's flux linkage, integrated from its voltage and current [V s]
        self._i_flux = np.zeros(2)  # its current at the last sample [A]
        self._loss_counted = [False, False, False, False]  # channel given up (counted in sensor_losses)
        self._check = _GapCheck(p, self.dt)  # the gap sensors against the coils' fluxes
        self.implausible = [False, False]  # gap sensor j contradicts the coil fluxes: ignored until clear()
        self.command_timeout = False  # the landing was started by the command hold timeout (a link watchdog)
        self.stop_gap = np.full(2, math.inf)
        self.min_stop_gap = math.inf
        self.mode = Mode(mode)
        self.reason = ""
        self.fault = ""
        self._load_kernels()
        self.counters = dict.fromkeys(
            ("holds", "hold_events", "longest_hold_us", "clipped", "rejected", "landings", "trips", "estops", "landed",
             "brakes", "brake_events", "sensor_gaps", "sensor_gap_events", "sensor_losses", "implausible"), 0)

    def _load_kernels(self) -> None:
        """Load (or compile: seconds) the numba kernels now, on scratch data, never in a sample."""
        s, a = np.zeros((3, 2)), np.zeros(2)
        s[0, :] = self.cfg["landing_gap"]
        de1, de2 = _deltas(self._p, s[0, 0], s[0, 1])
        _model_accel(self._p, de1, de2, 1.0, 1.0, a)
        _observe(self._p, self._Lo, s, a, s[0, 0], s[0, 1], 1.0, 1.0, np.zeros(2), np.zeros(2), np.zeros(2))
        _land_law(self._p, s, np.zeros((3, 2)), np.zeros(2), np.ones(2), False, np.zeros(2))
        _stop_gaps(self._p, s, np.ones(2), np.ones(2), self._u_max, np.zeros(2))
        _brake(self._p, s, np.ones(2), self._u_max, np.zeros(2))

    # -- commands from outside -------------------------------------------------------------
    def land(self, reason: str) -> None:
        """Start a controlled landing (ignored when already landing, landed or faulted); latched until clear()."""
        if self.mode in (Mode.LAND, Mode.LANDED, Mode.FAULT):
            return
        if self.mode == Mode.OFF:
            self.mode, self.reason = Mode.LANDED, reason  # nothing airborne under our control
            return
        self.mode = Mode.LAND
        self.reason = reason
        self.counters["landings"] += 1
        self._start_reference()
        # bumpless: the current loop's integral starts at what the nominal R misses of the last voltage
        self._ui[:] = self._u_last - self._p[_R] * np.asarray(self._i_last)

    def _start_reference(self) -> None:
        """The landing reference starts at the estimate, with the plate's own downward speed (<= v_ref)."""
        s, r = self.estimate, self._ref
        r[0, :] = s[0, :]
        r[1, :] = np.minimum(s[1, :], self._p[_VREF])
        r[2, :] = np.where(r[1, :] < 0.0, np.clip(-r[1, :] / CAPTURE_TIME, REF_ACCEL, CAPTURE_ACCEL), REF_ACCEL)

    def estop(self, reason: str) -> None:
        """Emergency stop: a latched fault that lands the plate (never a 0 V cut at hover)."""
        self.counters["estops"] += 1
        self._trip(f"e-stop: {reason}")

    def clear(self) -> None:
        """Acknowledge: LAND/LANDED/FAULT -> OFF, the latched fault is forgotten (counters stay)."""
        self.mode = Mode.OFF
        self.reason = ""
        self.fault = ""
        self._t_fresh = None
        self._braking = False
        self._flux_gap = [False, False]
        self._loss_counted = [False, False, False, False]
        self.implausible = [False, False]
        self.command_timeout = False
        self._check.reset()

    def _trip(self, reason: str) -> None:
        if not self.fault:
            self.fault = reason
        self.counters["trips"] += 1
        self.land(reason)

    # -- the sample ---------------------------------------------------------------------------
    def step(self, t_ns: int, y: Sequence[float] | np.ndarray | None, i: Sequence[float] | np.ndarray | None,
             u_cmd: Sequence[float] | np.ndarray | None,
             requested: Mode = Mode.RUN, bus: float | None = None,
             applied: Sequence[float] | np.ndarray | None = None) -> np.ndarray:
        """Voltages (2,) [V] to apply over [t, t + T).

        Args:
            t_ns: sample time [ns] (any monotonic clock).
            y (2,): measured load-point gaps [d1, d2] [m] (any sequence of two numbers; None or a
                non-finite entry: no sample, see "Lost sensor samples" in the module docstring).
            i (2,): measured coil currents [A] (any sequence of two numbers; None / non-finite likewise).
            u_cmd (2,): a command that arrived for this sample [V], or None.
            requested: the mode the commander asks for (RUN; LAND or OFF start a landing).
            bus: the coil drivers' measured bus voltage [V], when the board measures it: the brake
                can apply at most min(u_max, bus) (None: u_max).
            applied (2,): the voltages the coil drivers applied over the last period [V], when the board
                measures them (a failed bridge, PWM steps, the current limit); None: the last voltages this
                supervisor returned, clipped to the bus it was given.
        """
        y0, y1 = (math.nan, math.nan) if y is None else (float(y[0]), float(y[1]))
        i0, i1 = (math.nan, math.nan) if i is None else (float(i[0]), float(i[1]))
        if applied is not None and math.isfinite(applied[0]) and math.isfinite(applied[1]):
            self._u_prev[:] = (float(applied[0]), float(applied[1]))
        if self.implausible[0]:  # found implausible: never read again until clear()
            y0 = math.nan
        if self.implausible[1]:
            y1 = math.nan
        for n, v in enumerate((y0, y1, i0, i1)):  # a sensor that reads again may be given up again (counted)
            if math.isfinite(v):
                self._loss_counted[n] = False
        if self._flux_gap[0] or self._flux_gap[1]:  # a gap sensor given up: its gap from the coil's flux
            y0, y1 = self._gaps_from_flux(y0, y1, i0, i1)
        ok = (math.isfinite(y0), math.isfinite(y1), math.isfinite(i0), math.isfinite(i1))
        if not all(ok) and self._sensor_gap(t_ns, ok, (y0, y1, i0, i1)):
            return self.u
        for n in range(4):
            self._blind[n] = 0 if ok[n] else self._blind[n] + 1
        if not ok[2] or not ok[3]:  # a missing current: the board's coil model from the voltage it applied
            i0 = i0 if ok[2] else float(self._i_est[0])
            i1 = i1 if ok[3] else float(self._i_est[1])
        self._i_last = (i0, i1)
        if self.mode in (Mode.RUN, Mode.HOLD, Mode.LAND):  # (with a gap from its coil's flux: the other one)
            gone = (self._flux_gap[0], self._flux_gap[1])
            bad = self._check.step(y0, y1, (i0, i1), (ok[2], ok[3]), self._u_prev, self._r_est, gone)
            if bad == 2 or (bad >= 0 and gone[1 - bad]):
                return self._both_implausible(bad, y0, y1)
            if bad >= 0:
                y0, y1 = self._implausible(bad, y0, y1, i0, i1)
        else:
            self._check.reset()
        self._blind_now[0] = 0.0 if ok[0] else 1.0
        self._blind_now[1] = 0.0 if ok[1] else 1.0
        if not self._obs_ready:
            self.estimate[0, :] = (y0, y1)
            self.estimate[1:, :] = 0.0
            de1, de2 = _deltas(self._p, y0, y1)
            _model_accel(self._p, de1, de2, i0, i1, self._acc)
            self.estimate[2, :] = -self._acc  # bumpless: at rest, the model misses -a_m
            self._obs_ready = True
        else:
            _observe(self._p, self._Lo, self.estimate, self._acc, y0, y1, i0, i1, self._gated, self._blind_now, self._wild)
        if self.mode in (Mode.RUN, Mode.HOLD, Mode.LAND) and max(self._blind) > SENSOR_BLIND_SAMPLES:
            why = self._lost_channels(ok)
            if why:  # nothing left to land with (module docstring, "Lost sensor samples")
                self.counters["trips"] += 1
                self.fault = self.reason = why
                self.mode = Mode.FAULT
                self.u = np.zeros(2)
                return self.u
        u = self._step_modes(t_ns, u_cmd, requested, bus, i0, i1)
        self._coil_model(u, ok[2], ok[3])
        if bus is not None and math.isfinite(bus):  # what the bridges can apply of it (``applied``: what they did)
            U = max(float(bus), 0.0)
            np.clip(self._u_prev, -U, U, out=self._u_prev)
        return u

    def _lost_channels(self, ok: tuple[bool, ...]) -> str:
        """Channels without a finite sample for more than SENSOR_BLIND_SAMPLES (RUN, HOLD, LAND): land on the
        coil model (a current), on the coil's flux (a gap), wait for the flux landing's inputs (at most
        2 x SENSOR_BLIND_SAMPLES in all), or return the reason for FAULT ("" when none; module docstring)."""
        B = SENSOR_BLIND_SAMPLES
        blind = self._blind
        for j in (0, 1):  # a gap from its coil's flux must keep coming: else that end is blind, open loop
            if self._flux_gap[j] and blind[j] > B and self.mode != Mode.LANDED:
                if blind[2 + j] > B:
                    self._count_loss(2 + j)
                    cause = f"{_SENSOR_NAMES[2 + j]} lost too (no finite sample for {blind[2 + j]} samples)"
                elif blind[1 - j] > 0:
                    cause = f"{_SENSOR_NAMES[1 - j]} without a finite sample for {blind[1 - j]} samples"
                else:
                    cause = (f"coil {j + 1}'s current {self._i_last[j]:.2f} A at or under FLUX_GAP_MIN_CURRENT = "
                             f"{FLUX_GAP_MIN_CURRENT:g} A")
                return (f"{_SENSOR_NAMES[j]} lost, gap {j + 1} from coil {j + 1}'s flux: none for {blind[j]} "
                        f"samples (> {B}): {cause}; "
                        f"no landing without gap {j + 1}: 0 V, the plate drops onto its support")
        for n in (0, 1):
            if self._flux_gap[n] or blind[n] <= B:
                continue
            k = 1 - n
            lost = f"{_SENSOR_NAMES[n]} lost: no finite sample for {blind[n]} samples (> {B})"
            drop = "no landing without it: 0 V, the plate drops onto its support"
            if self._flux_gap[k]:
                why = f"gap {k + 1} already from coil {k + 1}'s flux"
            elif blind[k] > B:
                why = f"{_SENSOR_NAMES[k]} lost too"
            elif blind[2 + n] > B:
                why = f"{_SENSOR_NAMES[2 + n]} lost too: no flux for gap {n + 1}"
            elif ok[2 + n] and abs(self._i_last[n]) <= FLUX_GAP_MIN_CURRENT:
                why = (f"coil {n + 1}'s current {self._i_last[n]:.2f} A at or under FLUX_GAP_MIN_CURRENT = "
                       f"{FLUX_GAP_MIN_CURRENT:g} A: its flux tells too little of gap {n + 1}")
            elif blind[k] == 0 and ok[2 + n]:
                # the other gap and this coil's current measured: land on the coil's flux
                # its flux starts at this sample's current and the observer's gaps (which rode the blind samples)
                de = _deltas(self._p, self.estimate[0, 0], self.estimate[0, 1])
                self._flux_gap[n] = True
                self._lam_flux[n] = 2.0 * self._p[_K] * self._i_last[n] / de[n]
                self._i_flux[n] = self._i_last[n]
                blind[n] = 0
                self._count_loss(n)
                why = f"{lost}: landing on gap {n + 1} from coil {n + 1}'s flux"
                if self.mode == Mode.LAND:
                    self.fault = self.fault or why
                else:
                    self._trip(why)
                continue
            elif blind[n] > 2 * B:
                why = (f"no sample of {_SENSOR_NAMES[k]} and {_SENSOR_NAMES[2 + n]} together within "
                       f"{blind[n]} samples (> {2 * B}) to start the flux landing from")
            else:
                continue  # the other gap or this current only briefly blind: ride on the observer, decide again
            self._count_loss(n)
            return f"{lost}; {why}; {drop}"
        for n in (2, 3):
            if blind[n] > B and not self._loss_counted[n]:  # a current sensor: land on the coil model
                self._count_loss(n)
                if self.mode in (Mode.RUN, Mode.HOLD):
                    self._trip(f"{_SENSOR_NAMES[n]} lost: no finite sample for {blind[n]} samples "
                               f"(> {B}): landing on the board's coil model")
        return ""

    def _implausible(self, n: int, y0: float, y1: float, i0: float, i1: float) -> tuple[float, float]:
        """Gap sensor n reads what the coils' fluxes contradict (_GapCheck): ignored from now on, and the
        plate lands with gap n from coil n's flux, which starts at the check's flux estimate (the measured
        flux followed the wrong reading). Returns the gaps of this sample, gap n from that flux."""
        c = self._check
        y = [y0, y1]
        read, flux, tol = y[n], float(c.y_flux[n]), float(c.tol[n])
        i_n = i0 if n == 0 else i1
        self.implausible[n] = True
        self._flux_gap[n] = True
        self._lam_flux[n] = c.lam[n]
        self._i_flux[n] = i_n
        self._r_est[n] = c.r[n]  # the check's slow resistance: the coil model's has begun to follow the wrong gap
        self._count_loss(n)
        self.counters["implausible"] += 1
        y[n] = (2.0 * self._p[_K] * i_n / c.lam[n] - self._p[_Q] * y[1 - n]) / self._p[_P]
        # the observer followed the wrong reading: end n restarts from the flux (the landing starts from it)
        self.estimate[0, n] = y[n]
        self.estimate[1, n] = c.v_flux[n]
        self._gated[n] = 0.0
        c.restart_sensor(n)
        why = (f"{_SENSOR_NAMES[n]} implausible: reads {read * 1e3:.3f} mm, the coil fluxes say {flux * 1e3:.3f} mm "
               f"(off by more than {tol * 1e3:.3f} mm for {FLUX_CHECK_SAMPLES} samples): landing on gap {n + 1} "
               f"from coil {n + 1}'s flux")
        if self.mode == Mode.LAND:
            self.fault = self.fault or why
        else:
            self._trip(why)
        return y[0], y[1]

    def _both_implausible(self, bad: int, y0: float, y1: float) -> np.ndarray:
        """Both gap sensors contradict the coils' fluxes, at once (bad = 2) or one after the other (the first
        already a flux gap): no gap left to land with (module docstring): FAULT, 0 V (the plate falls away from
        the rail onto its support, whatever the sensors read)."""
        c = self._check
        new = (0, 1) if bad == 2 else (bad,)
        what = "at once" if bad == 2 else f"after gap sensor {2 - bad}"
        why = (f"gap sensors 1 and 2 implausible ({what}): read {y0 * 1e3:.3f}, {y1 * 1e3:.3f} mm, the coil fluxes "
               f"say {c.y_flux[0] * 1e3:.3f}, {c.y_flux[1] * 1e3:.3f} mm; no landing without a gap: 0 V, the plate "
               f"drops onto its support")
        for n in new:
            self.implausible[n] = True
            self._count_loss(n)
            self.counters["implausible"] += 1
        self.counters["trips"] += 1
        self.fault = self.reason = why
        self.mode = Mode.FAULT
        self.u = np.zeros(2)
        return self.u

    def _count_loss(self, n: int) -> None:
        """``sensor_losses`` counts each channel given up once (until it gives a finite sample again)."""
        if not self._loss_counted[n]:
            self._loss_counted[n] = True
            self.counters["sensor_losses"] += 1

    def _gaps_from_flux(self, y0: float, y1: float, i0: float, i1: float) -> tuple[float, float]:
        """The gap of a load point whose sensor was given up, from its coil's flux (module docstring, "Lost
        sensor samples"): lambda_j += T (u_j - R_j (i_j,prev + i_j)/2) (the voltage applied over the last
        period, trapezoid current), delta_j = 2K i_j / lambda_j, y_j = (delta_j - Q y_k) / P with the other
        load point's measured gap y_k. NaN (no sample) where it cannot be formed."""
        y = [y0, y1]
        i = (i0, i1)
        P, Q, K2 = self._p[_P], self._p[_Q], 2.0 * self._p[_K]
        for j in (0, 1):
            if not self._flux_gap[j]:
                continue
            if not math.isfinite(i[j]):  # no flux without the current: the sensor's own reading, if it is back
                continue
            self._lam_flux[j] += self.dt * (float(self._u_prev[j]) - self._r_est[j] * 0.5 * (self._i_flux[j] + i[j]))
            self._i_flux[j] = i[j]
            yk = y[1 - j]
            if math.isfinite(y[j]):  # the sensor is back: its gap, and the flux re-anchored on it
                de = P * y[j] + Q * yk if math.isfinite(yk) else math.nan
                if math.isfinite(de) and de > 0.0:
                    self._lam_flux[j] = K2 * i[j] / de
            elif math.isfinite(yk) and abs(i[j]) > FLUX_GAP_MIN_CURRENT and self._lam_flux[j] > 0.0:
                y[j] = (K2 * i[j] / self._lam_flux[j] - Q * yk) / P
            elif self.mode == Mode.LANDED:  # on the support, its current removed: the gap the landing ended at
                y[j] = float(self.estimate[0, j])
        return y[0], y[1]

    def _coil_model(self, u: np.ndarray, ok0: bool, ok1: bool) -> None:
        """Predict the currents of the next sample from the voltages u (2,) [V] just applied:
        lambda+ = lambda + T (u - R_j i), i+ = lambda+ delta / (2K) (u = R i + d lambda/dt, Eq. 5), with
        delta from the observer. R_j is learned per coil while its current is measured (low-pass, 50 ms) from
        the same equation, so a heated or cold coil does not bias the model; K cancels in lambda -> i."""
        de = _deltas(self._p, self.estimate[0, 0], self.estimate[0, 1])
        K2 = 2.0 * self._p[_K]
        for j, ok in ((0, ok0), (1, ok1)):
            ij = self._i_last[j]
            lam = K2 * ij / de[j]
            if ok and abs(ij) > 0.2 and self._lam[j] != 0.0 and not self._flux_gap[j]:  # R_j from the last voltage
                r = (float(self._u_prev[j]) - (lam - self._lam[j]) / self.dt) / ij
                r = min(max(r, 0.5 * self._p[_R]), 2.0 * self._p[_R])
                self._r_est[j] += self.dt / R_LEARN_TIME * (r - self._r_est[j])
            if not ok:
                lam = self._lam_pred[j]
            self._lam[j] = lam
            self._lam_pred[j] = lam + self.dt * (float(u[j]) - self._r_est[j] * ij)
            self._i_est[j] = self._lam_pred[j] * de[j] / K2
        self._u_prev[:] = u

    def _sensor_gap(self, t_ns: int, ok: tuple[bool, ...], raw: tuple[float, ...]) -> bool:
        """A non-finite or missing sample on some channel: counted; True when the board can do nothing but
        FAULT with 0 V (the plate on its support, or no estimate yet); False: carry on with the observer /
        coil model for that channel (``step`` faults after SENSOR_BLIND_SAMPLES in a row)."""
        self.counters["sensor_gaps"] += 1
        if self._blind[0] == 0 and self._blind[1] == 0 and self._blind[2] == 0 and self._blind[3] == 0:
            self.counters["sensor_gap_events"] += 1
        resting = self.mode in (Mode.OFF, Mode.LANDED, Mode.FAULT)
        if not (resting or not self._obs_ready):
            return False
        if self.mode != Mode.FAULT:
            why = ("the plate is on its support" if resting else "no estimate possible")
            self.fault = self.fault or (f"non-finite sensor reading (gaps {raw[0]!r}, {raw[1]!r}; currents "
                                        f"{raw[2]!r}, {raw[3]!r}): {why}")
            self.reason = self.fault
            self.counters["trips"] += 1
        self.mode = Mode.FAULT
        self.u = np.zeros(2)
        return True

    def _step_modes(self, t_ns: int, u_cmd: Sequence[float] | np.ndarray | None, requested: Mode,
                    bus: float | None, i0: float, i1: float) -> np.ndarray:
        """The mode machine of ``step``, after the observer."""
        mode = self.mode
        if mode == Mode.FAULT:
            self.u = np.zeros(2)
            return self.u
        U = self._u_max if bus is None else max(min(self._u_max, float(bus)), 1e-6)  # what the bridge can apply
        fresh = u_cmd is not None
        if fresh:
            a, b = float(u_cmd[0]), float(u_cmd[1])  # type: ignore[index]
            if not (math.isfinite(a) and math.isfinite(b)):
                self.counters["rejected"] += 1
                fresh = False
        if mode in (Mode.RUN, Mode.HOLD) and requested in (Mode.LAND, Mode.OFF):
            self.land(f"{requested.name} requested")
            mode = self.mode
        if mode in (Mode.RUN, Mode.HOLD):
            g = self.estimate[0]
            worst = max(abs(i0), abs(i1))
            if worst > self._i_max:
                self._trip(f"coil current {worst:.2f} A above i_max = {self._i_max:g} A")
            elif max(g[0], g[1]) > self.cfg["trip_gap_max"]:
                self._trip(f"gap {max(g[0], g[1]) * 1e3:.3f} mm above trip_gap_max = {self.cfg['trip_gap_max'] * 1e3:g} mm")
            mode = self.mode
        if mode == Mode.OFF:
            if fresh and requested == Mode.RUN:
                self.mode = mode = Mode.RUN
            else:
                self.u = np.zeros(2)
                return self.u
        if mode in (Mode.RUN, Mode.HOLD):
            cand = self._run_candidate(t_ns, mode, fresh, a if fresh else 0.0, b if fresh else 0.0)
            mode = self.mode
            if cand is not None:
                if self._safe(cand, U):
                    self.u = cand
                    return cand
                j = int(np.argmin(self.stop_gap))
                self._trip(f"predicted stopping gap {self.stop_gap[j] * 1e3:.3f} mm below trip_gap_min = "
                           f"{self.cfg['trip_gap_min'] * 1e3:g} mm at end {j + 1} (gap {self.estimate[0, j] * 1e3:.3f} mm, "
                           f"rate {self.estimate[1, j] * 1e3:+.1f} mm/s)")
                mode = self.mode
        u = np.empty(2)
        if mode == Mode.LAND and min(self.estimate[0, 0], self.estimate[0, 1]) >= self.cfg["landing_gap"]:
            self.mode = mode = Mode.LANDED
            self.counters["landed"] += 1
            self._braking = False
        if mode == Mode.LANDED:
            if max(abs(i0), abs(i1)) < I_OFF:
                u[:] = 0.0
            else:
                _land_law(self._p, self.estimate, self._ref, self._ui, np.array(self._i_last), True, u)
            self.u = u
            return u
        i_now = np.array(self._i_last)
        _land_law(self._p, self.estimate, self._ref, self._ui, i_now, False, u)
        safe = self._safe(u, U)
        if not safe or (self._braking and min(self.estimate[1, 0], self.estimate[1, 1]) < 0.0):
            if not self._braking:
                self.counters["brake_events"] += 1
            self._braking = True
            self.counters["brakes"] += 1
            _brake(self._p, self.estimate, i_now, U, u)
        elif self._braking:  # released: land from the state the brake left
            self._braking = False
            self._start_reference()
            self._ui[:] = 0.0
            _land_law(self._p, self.estimate, self._ref, self._ui, i_now, False, u)
        self.u = u
        return u

    def _run_candidate(self, t_ns: int, mode: Mode, fresh: bool, a: float, b: float) -> np.ndarray | None:
        """RUN/HOLD: the fresh command clipped to u_max, or the held one; None once the hold timed out (LAND)."""
        if fresh:
            lim = self._u_max
            ua = min(max(a, -lim), lim)
            ub = min(max(b, -lim), lim)
            if ua != a or ub != b:
                self.counters["clipped"] += 1
            self._u_last = np.array((ua, ub))
            self._t_fresh = t_ns
            if mode == Mode.HOLD:
                self.mode, self.reason = Mode.RUN, ""
            return self._u_last
        if self._t_fresh is None:
            self._t_fresh = t_ns
        if mode == Mode.RUN:
            self.mode, self.reason = Mode.HOLD, "command missing"
            self.counters["hold_events"] += 1
        held = t_ns - self._t_fresh
        if held <= self._hold_ns:
            self.counters["holds"] += 1
            if held > self.counters["longest_hold_us"] * 1000:
                self.counters["longest_hold_us"] = held // 1000
            return self._u_last
        self.command_timeout = True
        self.land(f"no command for {held * 1e-6:.1f} ms (hold_timeout {self._hold_ns * 1e-6:g} ms)")
        return None

    def _safe(self, cand: np.ndarray, U: float) -> bool:
        """Does the plate stop at least trip_gap_min from the rail at both ends if ``cand`` is applied for one
        sample, then the brake? Updates ``stop_gap`` and ``min_stop_gap``."""
        _stop_gaps(self._p, self.estimate, np.array(self._i_last), cand, U, self.stop_gap)
        low = float(min(self.stop_gap[0], self.stop_gap[1]))
        if low < self.min_stop_gap:
            self.min_stop_gap = low
        return low >= self.cfg["trip_gap_min"]

    def snapshot(self) -> dict[str, Any]:
        """Mode, reasons and counters as plain values (for /diagnostics and summaries)."""
        return {"mode": self.mode.name, "reason": self.reason, "fault": self.fault, **self.counters,
                "stop_gap_mm": [round(float(g) * 1e3, 4) if math.isfinite(g) else None for g in self.stop_gap],
                "min_stop_gap_mm": round(self.min_stop_gap * 1e3, 4) if math.isfinite(self.min_stop_gap) else None}
