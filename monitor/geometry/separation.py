"""Person model and ISO/TS 15066 speed and separation monitoring (SI units).

Pure arithmetic; docs/separation.md states the formulas and where each input comes from.

* S_p = S_h + S_r + S_s + C + Z_d + Z_r with S_h = v_h (T_r + T_s), S_r = v_r T_r,
  S_s = v_r^2 / (2 a), T_s = v_r / a (``protective_separation_m``);
* its inverse, the largest robot speed whose S_p fits in a separation d:
  v_max(d) = sqrt(b^2 + 2 a (d - C - Z_d - Z_r - v_h T_r)) - b, b = a T_r + v_h
  (``max_robot_speed_mps``);
* the command's speed scale: v_max(d) / programmed speed, capped at 1, and 0 when the robot is
  already faster than v_max(d) (``separation_speed_scale``);
* T_r as the sum of the monitor's own worst-case delays (``reaction_time_s``);
* C from the detection capability (ISO 13855, ``intrusion_distance_m``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

# ISO 13855: C = 8 (d - 14) mm for a detection capability d <= 40 mm, 850 mm (whole body,
# reaching over or through) above that. A camera person detector sees whole bodies, not hands.
WHOLE_BODY_INTRUSION_M = 0.85

# Default delays of the monitor's own configuration (monitor.toml defaults), seconds: see
# ``reaction_time_s``. 0.1 frame interval (10 fps) + 0.3 max frame age + 0.05 processing +
# 0.3 command ttl + 0.05 consumer reaction = 0.8 s.
DEFAULT_REACTION_TIME_S = 0.8


@dataclass(frozen=True)
class PersonModel:
    """A person as a vertical cylinder standing on the floor (metres).

    ``position_uncertainty_m`` is Z_d: the cylinder used for zone checks is widened by it.
    """

    radius_m: float = 0.3
    height_m: float = 1.9
    position_uncertainty_m: float = 0.1

    @property
    def zone_radius_m(self) -> float:
        return self.radius_m + self.position_uncertainty_m


@dataclass(frozen=True)
class SeparationParams:
    """ISO/TS 15066 speed and separation monitoring parameters (SI units).

    ``robot_speed_default_mps`` is the tool speed assumed when none is measured;
    ``position_uncertainty_m`` is Z_d, used when a function is not given one explicitly.
    """

    person_speed_mps: float = 1.6  # v_h (standard default when not measured)
    reaction_time_s: float = DEFAULT_REACTION_TIME_S  # T_r: see reaction_time_s()
    deceleration_mps2: float = 2.0  # a: robot braking deceleration (T_s = v_r / a)
    intrusion_distance_m: float = WHOLE_BODY_INTRUSION_M  # C (ISO 13855, whole body)
    robot_uncertainty_m: float = 0.02  # Z_r
    robot_speed_default_mps: float = 1.0
    position_uncertainty_m: float = 0.1  # Z_d


def _zd(params: SeparationParams, position_uncertainty_m: float | None) -> float:
    return params.position_uncertainty_m if position_uncertainty_m is None \
        else float(position_uncertainty_m)


def protective_separation_m(robot_speed_mps: float, params: SeparationParams,
                            position_uncertainty_m: float | None = None) -> float:
    """S_p = S_h + S_r + S_s + C + Z_d + Z_r (ISO/TS 15066), metres.

    S_h = v_h (T_r + T_s), S_r = v_r T_r, S_s = v_r^2 / (2 a), T_s = v_r / a. A non-finite
    speed gives infinity (never NaN): no separation is then enough.
    """
    v_r = abs(float(robot_speed_mps))
    if not math.isfinite(v_r):
        return math.inf
    p = params
    t_s = v_r / p.deceleration_mps2
    s_h = p.person_speed_mps * (p.reaction_time_s + t_s)
    s_r = v_r * p.reaction_time_s
    s_s = v_r * v_r / (2.0 * p.deceleration_mps2)
    return (s_h + s_r + s_s + p.intrusion_distance_m + _zd(p, position_uncertainty_m)
            + p.robot_uncertainty_m)


def max_robot_speed_mps(separation_m: float, params: SeparationParams,
                        position_uncertainty_m: float | None = None) -> float:
    """Largest robot speed whose S_p fits in ``separation_m`` (inverse of
    ``protective_separation_m``): sqrt(b^2 + 2 a (d - C - Z_d - Z_r - v_h T_r)) - b with
    b = a T_r + v_h; 0 when that is negative or the separation is not a finite number."""
    d = float(separation_m)
    if math.isnan(d):
        return 0.0
    p = params
    a = p.deceleration_mps2
    b = a * p.reaction_time_s + p.person_speed_mps
    room = (d - p.intrusion_distance_m - _zd(p, position_uncertainty_m)
            - p.robot_uncertainty_m - p.person_speed_mps * p.reaction_time_s)
    if room <= 0:
        return 0.0
    if math.isinf(room):
        return math.inf
    return max(0.0, math.sqrt(b * b + 2 * a * room) - b)


def separation_speed_scale(separation_m: float, params: SeparationParams,
                           programmed_speed_mps: float, tool_speed_mps: float | None = None,
                           position_uncertainty_m: float | None = None) -> float:
    """Largest fraction of the programmed robot speed that v_max(separation) allows, in [0, 1].

    ``min(1, v_max(d) / programmed_speed_mps)``; 1.0 (RUN) only where v_max allows the full
    programmed speed. 0.0 (STOP) when the separation is NaN, when v_max is 0, or when the tool
    is already moving faster than v_max(d) (``tool_speed_mps``): S_p at that speed exceeds d,
    and slowing down can no longer keep the separation. A programmed speed that is not a
    positive finite number also gives 0.0.
    """
    v = float(programmed_speed_mps)
    if not (math.isfinite(v) and v > 0):
        return 0.0
    v_max = max_robot_speed_mps(separation_m, params, position_uncertainty_m)
    if tool_speed_mps is not None:
        speed = abs(float(tool_speed_mps))
        if not math.isfinite(speed) or speed > v_max:
            return 0.0
    if not v_max > 0:
        return 0.0
    return min(1.0, v_max / v)


def intrusion_distance_m(detection_capability_mm: float | None) -> float:
    """C of ISO 13855 from the detection capability d (mm): 8 (d - 14) mm, at least 0, for
    d <= 40 mm; 850 mm for larger d or None (whole-body detection, as a person detector)."""
    if detection_capability_mm is None or not detection_capability_mm <= 40.0:
        return WHOLE_BODY_INTRUSION_M
    return max(0.0, 8.0 * (float(detection_capability_mm) - 14.0)) / 1000.0


@dataclass(frozen=True)
class ReactionBudget:
    """The monitor's worst-case delays between a person stepping in and the robot starting to
    brake, seconds. Each comes from the configuration, not from a guess:

    * ``frame_interval_s``: the person may step in just after a frame was captured;
    * ``max_frame_age_s``: a frame may be this old when it is decided on (policy.max_frame_age);
    * ``processing_s``: detection, zone check and policy step of that frame;
    * ``command_ttl_s``: a consumer keeps acting on the last RUN this long when the STOP is lost
      (bus.ttl_ms);
    * ``consumer_reaction_s``: the robot controller's reaction to a STOP command;
    * ``pose_age_s``: how old the tool pose may be (policy.pose_timeout) when separation
      monitoring is on (the tool moved on meanwhile).
    """

    frame_interval_s: float = 0.1
    max_frame_age_s: float = 0.3
    processing_s: float = 0.05
    command_ttl_s: float = 0.3
    consumer_reaction_s: float = 0.05
    pose_age_s: float = 0.0

    def total_s(self) -> float:
        return reaction_time_s(self.frame_interval_s, self.max_frame_age_s, self.processing_s,
                               self.command_ttl_s, self.consumer_reaction_s, self.pose_age_s)


def reaction_time_s(frame_interval_s: float, max_frame_age_s: float, processing_s: float,
                    command_ttl_s: float, consumer_reaction_s: float,
                    pose_age_s: float = 0.0) -> float:
    """T_r as the sum of the worst-case delays (see ``ReactionBudget``), seconds.

    Summed, not overlapped: a frame captured just after the person stepped in, decided on at
    its maximum age, whose STOP is lost so that the consumer waits out the ttl, is the case T_r
    must cover. Raises ValueError for a negative or non-finite part.
    """
    parts = {"frame_interval_s": frame_interval_s, "max_frame_age_s": max_frame_age_s,
             "processing_s": processing_s, "command_ttl_s": command_ttl_s,
             "consumer_reaction_s": consumer_reaction_s, "pose_age_s": pose_age_s}
    for name, value in parts.items():
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"reaction time part {name} must be a finite number >= 0, "
                             f"got {value!r}")
    return float(sum(parts.values()))


def describe_separation(params: SeparationParams, programmed_speed_mps: float,
                        budget: ReactionBudget | None = None) -> str:
    """One paragraph for ``monitor run`` to print at start: T_r and its parts, C and why, and
    S_p at rest and at the programmed speed (the separation below which the command slows,
    and the one below which it stops)."""
    p = params
    tr = (f"T_r = {p.reaction_time_s:.3f} s" if budget is None else
          f"T_r = {p.reaction_time_s:.3f} s (configuration: frame interval "
          f"{budget.frame_interval_s:.3f} + max frame age {budget.max_frame_age_s:.3f} + "
          f"processing {budget.processing_s:.3f} + command ttl {budget.command_ttl_s:.3f} + "
          f"consumer {budget.consumer_reaction_s:.3f} + pose age {budget.pose_age_s:.3f} = "
          f"{budget.total_s():.3f} s)")
    c_why = ("ISO 13855 whole-body value for detection capability > 40 mm"
             if abs(p.intrusion_distance_m - WHOLE_BODY_INTRUSION_M) < 1e-9
             else "from the zone file")
    s_full = protective_separation_m(programmed_speed_mps, p)
    s_rest = protective_separation_m(0.0, p)
    return (f"Separation monitoring (ISO/TS 15066): {tr}; v_h = {p.person_speed_mps:g} m/s, "
            f"a = {p.deceleration_mps2:g} m/s², C = {p.intrusion_distance_m:.3f} m ({c_why}), "
            f"Z_d = {p.position_uncertainty_m:.3f} m, Z_r = {p.robot_uncertainty_m:.3f} m. "
            f"Full programmed speed {programmed_speed_mps:g} m/s needs S_p = {s_full:.2f} m; "
            f"closer, the speed scale is v_max(d) / {programmed_speed_mps:g} m/s; below "
            f"S_p = {s_rest:.2f} m (robot at rest) the command is STOP.")
