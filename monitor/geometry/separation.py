"""Person model and ISO/TS 15066 speed and separation monitoring (SI units)."""

from __future__ import annotations

import math
from dataclasses import dataclass


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

    ``robot_speed_default_mps`` is the tool speed assumed when none is measured.
    """

    person_speed_mps: float = 1.6  # v_h (standard default when not measured)
    reaction_time_s: float = 0.1  # T_r: detection + logic + command latency
    deceleration_mps2: float = 2.0  # a: robot braking deceleration (T_s = v_r / a)
    intrusion_distance_m: float = 0.2  # C
    robot_uncertainty_m: float = 0.02  # Z_r
    robot_speed_default_mps: float = 1.0


def protective_separation_m(robot_speed_mps: float, params: SeparationParams,
                            position_uncertainty_m: float) -> float:
    """S_p = S_h + S_r + S_s + C + Z_d + Z_r (ISO/TS 15066), metres.

    S_h = v_h (T_r + T_s), S_r = v_r T_r, S_s = v_r^2 / (2 a), T_s = v_r / a.
    """
    v_r = abs(float(robot_speed_mps))
    p = params
    t_s = v_r / p.deceleration_mps2
    s_h = p.person_speed_mps * (p.reaction_time_s + t_s)
    s_r = v_r * p.reaction_time_s
    s_s = v_r * v_r / (2.0 * p.deceleration_mps2)
    return s_h + s_r + s_s + p.intrusion_distance_m + position_uncertainty_m + p.robot_uncertainty_m


def max_robot_speed_mps(separation_m: float, params: SeparationParams,
                        position_uncertainty_m: float) -> float:
    """Largest robot speed whose S_p fits in ``separation_m`` (inverse of
    ``protective_separation_m``): sqrt(b^2 + 2 a (d - C - Z_d - Z_r - v_h T_r)) - b with
    b = a T_r + v_h; 0 when that is negative."""
    p = params
    a = p.deceleration_mps2
    b = a * p.reaction_time_s + p.person_speed_mps
    room = (separation_m - p.intrusion_distance_m - position_uncertainty_m
            - p.robot_uncertainty_m - p.person_speed_mps * p.reaction_time_s)
    if room <= 0:
        return 0.0
    return max(0.0, math.sqrt(b * b + 2 * a * room) - b)

