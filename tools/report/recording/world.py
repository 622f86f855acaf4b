"""`world/`: a simulated run's bodies (crane vessel, boom, feeder with its cargo, hook block,
rope) as meshes logged once, moved by their true poses relative to the boom tip. A recording of
a real run has no such poses: its `world/` holds the boom tip alone."""

from __future__ import annotations

import numpy as np

from boomtip.tools.report.recording.convention import Recording

__all__ = ["BODY_CLASS", "WORLD_RATE_HZ", "log_world"]

WORLD_RATE_HZ = 10.0  # the bodies' poses: smooth to the eye, a pose per body per sample in the file
BODY_CLASS = {"crane": "crane_vessel", "feeder": "feeder_vessel", "boom": "boom", "block": "hook_block", "rope": "rope"}
NOT_DRAWN = ("sea",)  # a 4 km plane: it hides the ships from below and says nothing


def log_world(recording: Recording, source) -> list[str]:
    """Log the bodies of a simulated `source` over the span the recording saw; the entity paths."""
    poses_of = getattr(source, "bodies_about_tip", None)
    bodies = getattr(getattr(source, "world", None), "bodies", None)
    t0, t1 = recording.t_range_s
    if poses_of is None or not bodies or not np.isfinite(t0):
        return []
    t_s = np.arange(t0, t1 + 0.5 / WORLD_RATE_HZ, 1.0 / WORLD_RATE_HZ)
    poses = poses_of(t_s)
    paths = []
    for body in bodies:
        if body.name in NOT_DRAWN or body.name not in poses:
            continue
        R, p, scale = poses[body.name]
        path = f"world/{body.name}"
        recording.mesh(f"{path}/mesh", body.vertices, body.triangles, BODY_CLASS.get(body.name, "cargo"))
        recording.poses(path, t_s, np.broadcast_to(R, (len(t_s), 3, 3)), np.broadcast_to(p, (len(t_s), 3)),
                        None if scale is None else np.broadcast_to(scale, (len(t_s), 3)))
        paths.append(path)
    return paths
