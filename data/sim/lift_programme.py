"""The lift's crane programme (`world.lift.program`): the joints that bring the hanging load over
its set-down spot on the feeder, lower it to a pause above the deck, wait, and set it down.

Geometry at rest (no waves, no swing, a rigid boom): the vessel frame's origin on the calm
waterline; the tip at c + b (cos nu, sin nu, 0) + (0, 0, h) + L (cos mu cos nu, cos mu sin nu,
sin mu) (data/crane_model.py); the hook straight below it at the rope's length; the load's
underside `block + slings + load height` below the hook.
"""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.crane_model import CraneParams
from boomtip.data.sim.crane_joints import CraneJointProfiles, JointLimits, JointMove, JointProfile, move_timing
from boomtip.data.sim.run import SimulatedRun
from boomtip.data.sim.scene import BULWARK_THICKNESS_M, open_deck_x

SETTLE_S = 10.0  # after the hoist stops: the load rests on the deck, the rope slack
MIN_ROPE_M = 1.0  # the shortest rope the programme may start from
APPROACH_START_S = 1.0
# a load is brought in gently: its slew and luff at these fractions of the drives' rate and
# acceleration limits (at the limits, a 2 deg slew sets a 60 m pendulum swinging by metres)
APPROACH_RATE_FRACTION, APPROACH_ACC_FRACTION = 0.25, 0.1


class LiftProgramError(ValueError):
    """A programme the crane and the feeder cannot carry out: the message names the key."""


class LiftPlan:
    """The programme's joint targets and its times, from the world and the true crane."""

    def __init__(self, s: SimulatedRun, params: CraneParams) -> None:
        lift, feeder = s.world.lift, s.world.feeder.geometry
        prog = lift.program
        self._check_on_deck(s)
        target = np.asarray(feeder.position_m[:2], float) + np.asarray(prog.target_deck_m, float)
        c = np.asarray(params.c, float)
        d = target - c[:2]
        reach = (float(np.hypot(*d)) - params.b) / params.L
        if not 0.0 < reach < 1.0:
            raise LiftProgramError(f"world.lift.program.target_deck_m {list(prog.target_deck_m)}: the spot lies "
                             f"{np.hypot(*d):.1f} m from the slewing axis, beyond the boom's reach "
                             f"({params.b:g} m to {params.b + params.L:g} m)")
        self.slew_rad, self.luff_rad = math.atan2(d[1], d[0]), math.acos(reach)
        tip_z = c[2] + params.h + params.L * math.sin(self.luff_rad)
        deck_z = feeder.position_m[2] + feeder.freeboard_m
        below_hook = s.installation.crane.block_height_m + lift.sling_height_m + lift.size()[2]
        self.rope_at = lambda clearance_m: tip_z - deck_z - below_hook - clearance_m
        if self.rope_at(prog.start_clearance_m) <= MIN_ROPE_M:
            raise LiftProgramError(f"world.lift.program.start_clearance_m = {prog.start_clearance_m:g} m: the load would hang "
                             f"above the boom tip ({tip_z - deck_z:.1f} m above the deck)")
        lim = JointLimits()
        self.t_lower_s = prog.lower_start_s
        t_down = move_timing(prog.start_clearance_m - prog.pause_clearance_m, prog.lower_speed_mps, lim.hoist_acc_max_m_s2)[2]
        self.t_land_s = self.t_lower_s + t_down + prog.wait_s
        t_land = move_timing(prog.pause_clearance_m + prog.slack_m, prog.land_speed_mps, lim.hoist_acc_max_m_s2)[2]
        self.t_end_s = self.t_land_s + t_land + SETTLE_S
        acc, gentle, soft = lim.hoist_acc_max_m_s2, APPROACH_RATE_FRACTION, APPROACH_ACC_FRACTION
        self.joints = CraneJointProfiles(
            JointProfile(self.slew_rad + math.radians(prog.approach_slew_deg),
                         [JointMove(t_start_s=APPROACH_START_S, target=self.slew_rad, v_max=gentle * lim.slew_rate_max_rad_s,
                                    a_max=soft * lim.slew_acc_max_rad_s2)]),
            JointProfile(self.luff_rad + math.radians(prog.approach_luff_deg),
                         [JointMove(t_start_s=APPROACH_START_S, target=self.luff_rad, v_max=gentle * lim.luff_rate_max_rad_s,
                                    a_max=soft * lim.luff_acc_max_rad_s2)]),
            JointProfile(self.rope_at(prog.start_clearance_m), [
                JointMove(t_start_s=self.t_lower_s, target=self.rope_at(prog.pause_clearance_m), v_max=prog.lower_speed_mps, a_max=acc),
                JointMove(t_start_s=self.t_land_s, target=self.rope_at(-prog.slack_m), v_max=prog.land_speed_mps, a_max=acc),
            ]),
        )

    @staticmethod
    def _check_on_deck(s: SimulatedRun) -> None:
        """The load's footprint about the spot must lie on the feeder's open deck."""
        g, lift = s.world.feeder.geometry, s.world.lift
        x, y = lift.program.target_deck_m
        half = 0.5 * math.hypot(*lift.size()[:2])  # any heading
        x0, x1 = open_deck_x(s)
        y_max = g.beam_m / 2 - BULWARK_THICKNESS_M
        if not (x0 + half <= x <= x1 - half and abs(y) + half <= y_max):
            raise LiftProgramError(f"world.lift.program.target_deck_m {[x, y]}: a {lift.size()[0]:g} x {lift.size()[1]:g} m "
                             f"load there would not lie on the feeder's open deck (x {x0:.1f}..{x1:.1f} m, "
                             f"|y| < {y_max:.1f} m, feeder body frame)")

