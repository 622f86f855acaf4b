"""The feeder frame's definition and the filter's states expressed in it.

The filter runs in a map frame (the first deck, the tilted level frame as the MRU and the
surveyed mount give it). The estimates are the feeder frame (origin at the deck point straight
below the boom tip at the first LiDAR frame, z along the deck normal, x along the centre line)
in the heading frame at the tip, levelled with the levelling calibration, with the
calibration's and the centre line's own uncertainty added to the variances.

What the definition is known from grows with the run: the deck normals (the tilt), the own
hull's edges (the rotation about the vertical) and the feeder's hull edges (the centre line).
`frame_at(data, t)` is the definition from what was known at t: at the run's end it is the best
offline estimate of a recording (`feeder_estimates.csv`); `frame_history` is what a live
controller had as the run went (`feeder_estimates_online.csv`). The frame itself stays the first
frame's; only the estimate of it changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from boomtip.fusion.level_calibration import Tilt, correction, median_and_sigma, tilt_from_normals, with_heading, within_the_survey
from boomtip.fusion.models.relative_motion import rotation
from boomtip.fusion.records import Records
from boomtip.data.poses import inverse, matrices_rpy, pose_matrix, rpy_matrices, transform

UPDATE_EVERY_S = 1.0  # the causal definition is recomputed this often (and at the last row)
JACOBIAN_STEP = 1e-6  # central differences' step in the map's pose (m, rad)
ROWS_AT_ONCE = 2048  # recorded states put in the feeder frame in one batch (a batch's arrays: ~4 MB)

# A recorded state's row (the estimator's records, fusion.records): its time, the filter's pose
# and rates (12) and their covariance (12 x 12), the tip's velocity relative to the vessel, the
# LiDAR's place in the level frame (the levelling turns about it), and the frame's time with how
# many centre lines and hull edges were known by then.
REC_T, REC_X, REC_P = 0, slice(1, 13), slice(13, 157)
REC_TIP, REC_PIVOT, REC_KNOWN = slice(157, 160), slice(160, 163), slice(163, 166)
RECORD_WIDTH = 166


def state_record(t_s: float, x: np.ndarray, P: np.ndarray, tip_velocity: np.ndarray, lidar_level: np.ndarray,
                 edges_known: tuple[float, int, int]) -> np.ndarray:
    """One row of the records: x and P the filter's at its time t_s (their pose and rates are
    kept); edges_known: (the frame's time, centre lines, hull edges)."""
    row = np.empty(RECORD_WIDTH)
    row[REC_T], row[REC_X], row[REC_P] = t_s, x[:12], P[:12, :12].ravel()
    row[REC_TIP], row[REC_PIVOT], row[REC_KNOWN] = tip_velocity, lidar_level, edges_known
    return row


@dataclass
class StateRows:
    """A block of recorded states, as arrays."""

    t_s: np.ndarray  # (N,)
    x: np.ndarray  # (N, 12) pose and rates in the map frame
    P: np.ndarray  # (N, 12, 12)
    tips: np.ndarray  # (N, 3) the tip's velocity relative to the vessel
    pivots: np.ndarray  # (N, 3) the LiDAR's place in the level frame

    @classmethod
    def of(cls, rows: np.ndarray) -> "StateRows":
        return cls(rows[:, REC_T], rows[:, REC_X], rows[:, REC_P].reshape(-1, 12, 12), rows[:, REC_TIP], rows[:, REC_PIVOT])

    def part(self, i: int, j: int) -> "StateRows":
        """Rows i..j-1."""
        return StateRows(self.t_s[i:j], self.x[i:j], self.P[i:j], self.tips[i:j], self.pivots[i:j])


@dataclass
class FrameData:
    """What the definition is estimated from, each with the time it became known."""

    t_normals_s: np.ndarray  # (N,) LiDAR deck normals' times
    normals_level: np.ndarray  # (N, 3) in the (tilted) level frame
    t_hull_s: np.ndarray  # (H,) the own hull's edge direction in the level frame (rad)
    hull_yaws_rad: np.ndarray
    t_lines_s: np.ndarray  # (L,) the feeder's centre line's yaw in the map frame (rad)
    line_yaws_rad: np.ndarray
    x0: np.ndarray  # the filter's first state: the map frame's first deck
    T_level_map0: np.ndarray
    min_span_s: float  # deck normals needed before the tilt applies
    mount_sigma_rad: float  # the survey's 1-sigma of the LiDAR mount
    line_prior_sigma_rad: float  # the centre line's 1-sigma with under three frames' edges


@dataclass
class FeederFrameEstimate:
    """The feeder frame's definition as known at some time."""

    tilt: Tilt | None  # None: not calibrated, the survey stands
    C: np.ndarray  # the levelling correction (tilted level -> corrected)
    T_map_feeder: np.ndarray  # the feeder frame in the map frame
    line: tuple[float, int] | None  # the centre line's yaw in the map frame, frames it was found in
    line_sigma_rad: float
    rejected: str | None = None  # why a tilt beyond the survey was not taken

    def sigmas(self, survey_sigma_rad: float) -> tuple[float, float]:
        """1-sigma of the levelling about x and y, and about the vertical: the calibration's once
        it has one, else the survey's."""
        t = self.tilt
        return (t.sigma_rad if t is not None else survey_sigma_rad,
                t.rz_sigma_rad if t is not None and t.rz_sigma_rad is not None else survey_sigma_rad)


def levelling_at(d: FrameData, t_s: float = math.inf, heading_alone: bool = False) -> tuple[Tilt | None, str | None]:
    """The levelling calibration from what was known at t_s, and why a tilt was not taken.
    heading_alone: the own hull's rotation about the vertical also before the deck normals span
    min_span_s (the survey's tilt, span 0), as soon as three edges have it."""
    n = int(np.searchsorted(d.t_normals_s, t_s, side="right"))
    hull = d.hull_yaws_rad[:int(np.searchsorted(d.t_hull_s, t_s, side="right"))]
    tilt, why = None, None
    if n:
        tilt = tilt_from_normals(d.t_normals_s[:n], d.normals_level[:n], d.min_span_s)
        tilt, why = within_the_survey(tilt, d.mount_sigma_rad)
    if tilt is None and heading_alone:
        heading = with_heading(Tilt(0.0, 0.0, d.mount_sigma_rad, 0.0), hull)
        return (heading if heading.rz_sigma_rad is not None else None), why
    return with_heading(tilt, hull), why


def frame_at(d: FrameData, t_s: float = math.inf, heading_alone: bool = False) -> FeederFrameEstimate:
    """The definition from what was known at t_s (all of it by default); heading_alone: see
    levelling_at."""
    tilt, why = levelling_at(d, t_s, heading_alone)
    C = correction(tilt)
    # The origin: straight below the tip along the calibrated vertical, on the first deck.
    n0 = rotation(*d.x0[3:6])[:, 2]
    down = C.T @ np.array([0.0, 0.0, -1.0])
    s = float(n0 @ d.x0[:3]) / float(n0 @ down)  # from the tip, the level frame's origin
    origin_map = transform(inverse(d.T_level_map0), s * down)
    # The centre line's own error is a constant error of every yaw: its 1-sigma from the frames'
    # spread (median_and_sigma), or the prior of the feeder lying along the crane's heading.
    # A median, so a frame that took a cargo edge does not count.
    yaws = d.line_yaws_rad[:int(np.searchsorted(d.t_lines_s, t_s, side="right"))]
    line, line_sigma = None, d.line_prior_sigma_rad
    if len(yaws):
        median, sigma = median_and_sigma(yaws)
        line = (median, len(yaws))
        if len(yaws) >= 3:
            line_sigma = sigma
    psi0 = line[0] if line is not None else 0.0
    return FeederFrameEstimate(tilt, C, pose_matrix(*origin_map, 0.0, 0.0, psi0), line, line_sigma, why)


def frame_history(d: FrameData, t_rows_s: np.ndarray, every_s: float = UPDATE_EVERY_S) -> tuple[np.ndarray, list[FeederFrameEstimate]]:
    """The definition a live controller had: recomputed from the data up to each of the times
    t_rows[0] + k * every_s and the last row's time. Recomputed rather than updated: the Hann
    window of the tilt changes with the span (a running sum of its weights is not exact) and
    the edges' medians need their samples; each update is O(n), 60-700 of them in a run.
    The own hull's heading applies as soon as it is known (a few seconds), not only with the
    tilt's 30 s: a live controller's yaw is the better for it from the first seconds. The offline
    definition keeps the tilt's rule."""
    t0, t1 = float(t_rows_s[0]), float(t_rows_s[-1])
    t_updates = np.r_[t0 + every_s * np.arange(max(1, math.ceil((t1 - t0) / every_s))), t1]
    t_updates = np.unique(t_updates[t_updates <= t1])
    return t_updates, [frame_at(d, float(t), heading_alone=True) for t in t_updates]


def estimates_in_feeder_frame(states: StateRows, frame: FeederFrameEstimate, sigma_level: float,
                              mru_bias_sigma_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N, 6) poses, (N, 6) rates and (N, 12) variances of recorded states in the feeder frame
    as `frame` defines it, vectorised over the rows."""
    if len(states.t_s) == 0:
        return np.zeros((0, 6)), np.zeros((0, 6)), np.zeros((0, 12))
    # The levelling's own uncertainty. Corrected about the LiDAR, a tilt moves the deck below it
    # sideways by its lever. The MRU's bias tilts the same sensor-to-level rotation as a mount
    # error and is calibrated with it; what it moves besides is the tip about the vessel's
    # origin, which the estimate (relative to the tip) sees only in z, by the horizontal offset.
    s_lvl, s_rz = frame.sigmas(sigma_level)
    x = np.array(states.x, dtype=float)
    x[:, 6:9] -= states.tips  # the state's rates are the vessel's: relative to the tip
    pivot, P = states.pivots, states.P
    y, J = feeder_pose_jacobians(x[:, :6], frame.C, pivot, frame.T_map_feeder)
    lever = np.linalg.norm(y[:, :3] - pivot, axis=1)
    extra = np.column_stack([(lever * s_lvl) ** 2, (lever * s_lvl) ** 2, (np.hypot(y[:, 0], y[:, 1]) * mru_bias_sigma_rad) ** 2,
                             np.full(len(y), s_lvl ** 2), np.full(len(y), s_lvl ** 2),
                             np.full(len(y), frame.line_sigma_rad ** 2 + s_rz ** 2)])
    # diag(J P J^T) row by row: sum over k, l of J_ik P_kl J_il
    var_pose = np.einsum("nik,nkl,nil->ni", J, P[:, :6, :6], J) + extra
    var_rates = np.einsum("nik,nkl,nil->ni", J, P[:, 6:12, 6:12], J)
    rates = np.einsum("nij,nj->ni", J, x[:, 6:12])
    return y, rates, np.concatenate([var_pose, var_rates], axis=1)


def records_in_feeder_frame(records: Records, which: np.ndarray, frames: list[FeederFrameEstimate], sigma_level: float,
                            mru_bias_sigma_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """estimates_in_feeder_frame of every recorded state (`records`: fusion.records.Records of
    state_record rows), row i in the definition frames[which[i]]; read ROWS_AT_ONCE rows at a
    time: a long run's states at once would be tens of MB more at the run's peak, its end."""
    n = len(records)
    pose, rates, var = np.empty((n, 6)), np.empty((n, 6)), np.empty((n, 12))
    for a in range(0, n, ROWS_AT_ONCE):
        block = StateRows.of(records.read(a, a + ROWS_AT_ONCE))
        w = which[a:a + ROWS_AT_ONCE]
        for i, j in _runs(w):  # rows in one definition, each run vectorised
            pose[a + i:a + j], rates[a + i:a + j], var[a + i:a + j] = estimates_in_feeder_frame(
                block.part(i, j), frames[w[i]], sigma_level, mru_bias_sigma_rad)
    return pose, rates, var


@dataclass
class CausalEstimates:
    """The estimates as a live controller had them: each row in the definition known at its time."""

    t_s: np.ndarray  # (T,) the offline estimates' times
    pose: np.ndarray  # (T, 6)
    rates: np.ndarray  # (T, 6)
    var: np.ndarray  # (T, 12)
    t_updates_s: np.ndarray  # (U,) when the definition was recomputed
    frames: list[FeederFrameEstimate]  # (U,) the definition from the data up to then
    history: np.ndarray  # (U, len(HISTORY_COLUMNS)) the definition's figures at each update
    calibrated_at_s: float  # the first update with a tilt from the deck normals (nan: none in the run)


# feeder_calibration.csv: the levelling calibration (tilt about the level x, y, z axes and its
# 1-sigma: the survey's before it applies; span of deck normals it is from, 0 before), the
# centre line's yaw in the map frame and its 1-sigma, the origin in the map frame
HISTORY_COLUMNS = ("t", "about_x_deg", "about_y_deg", "about_z_deg", "sigma_x_deg", "sigma_y_deg", "sigma_z_deg", "span_s",
                   "centre_line_deg", "centre_line_sigma_deg", "origin_x_m", "origin_y_m", "origin_z_m")


def history_row(t_s: float, f: FeederFrameEstimate, survey_sigma_rad: float) -> list[float]:
    s_lvl, s_rz = f.sigmas(survey_sigma_rad)
    t = f.tilt or Tilt(0.0, 0.0, s_lvl, 0.0)
    deg = np.degrees([t.rx_rad, t.ry_rad, t.rz_rad, s_lvl, s_lvl, s_rz, f.line[0] if f.line else 0.0, f.line_sigma_rad])
    return [t_s, *deg[:6], t.span_s, *deg[6:], *f.T_map_feeder[:3, 3]]


def causal_estimates(records: Records, d: FrameData, keep: np.ndarray, sigma_level: float,
                     mru_bias_sigma_rad: float) -> CausalEstimates:
    """The recorded states (`records`, as records_in_feeder_frame takes them) expressed causally,
    each row in the definition of the last update at or before its time; keep: the rows the
    offline estimates keep (one per time)."""
    t = records.column(REC_T)
    t_updates, frames = frame_history(d, t)
    which = np.searchsorted(t_updates, t, side="right") - 1
    pose, rates, var = records_in_feeder_frame(records, which, frames, sigma_level, mru_bias_sigma_rad)
    history = np.array([history_row(float(u), f, sigma_level) for u, f in zip(t_updates, frames)])
    calibrated = [float(u) for u, f in zip(t_updates, frames) if f.tilt is not None and f.tilt.span_s > 0]
    return CausalEstimates(t[keep], pose[keep], rates[keep], var[keep], t_updates, frames, history,
                           calibrated[0] if calibrated else math.nan)


def _runs(labels: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of the runs of equal consecutive labels."""
    edges = np.r_[0, np.flatnonzero(np.diff(labels)) + 1, len(labels)]
    return list(zip(edges[:-1].tolist(), edges[1:].tolist()))



def feeder_pose_jacobians(pose_map_level: np.ndarray, C: np.ndarray, pivot: np.ndarray,
                          T_map_feeder: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The feeder frame's poses (N, 6) and their Jacobians (N, 6, 6, central differences)
    w.r.t. the map's poses (N, 6); pivot: the LiDAR's position at each (N, 3)."""
    n = len(pose_map_level)
    steps = JACOBIAN_STEP * np.eye(6)
    # each row, then each row stepped up and down along each axis: one batch of 13 N poses
    batch = np.concatenate([pose_map_level[:, None, :], pose_map_level[:, None, :] + steps, pose_map_level[:, None, :] - steps], axis=1)
    y = feeder_poses(batch.reshape(-1, 6), C, np.repeat(pivot, 13, axis=0), T_map_feeder).reshape(n, 13, 6)
    d = y[:, 1:7] - y[:, 7:13]  # (N, step axis j, output i)
    d[..., 3:] = (d[..., 3:] + np.pi) % (2 * np.pi) - np.pi
    return y[:, 0], np.swapaxes(d, 1, 2) / (2 * JACOBIAN_STEP)


def feeder_poses(pose_map_level: np.ndarray, C: np.ndarray, pivot: np.ndarray, T_map_feeder: np.ndarray) -> np.ndarray:
    """The feeder frame's poses (N, 6) in the corrected heading frame: the map's poses in the
    level frame (N, 6), turned by the levelling correction C about the LiDAR (pivot, (N, 3)),
    composed with the feeder frame's place in the map."""
    R = rpy_matrices(pose_map_level[:, 3:])
    R_out = C @ R @ T_map_feeder[:3, :3]  # (N, 3, 3)
    t_map = np.einsum("nij,j->ni", R, T_map_feeder[:3, 3]) + pose_map_level[:, :3]
    t_out = t_map @ C.T + pivot - pivot @ C.T
    return np.column_stack([t_out, matrices_rpy(R_out)])
