"""Registration of the feeder's returns to a model of the feeder built online, seeded with
the filter's prediction instead of kiss-icp's constant-velocity prior, which fails on wave
motion (upstream issue 257).

The model is a keyframe: the feeder's returns above its deck (bulwarks, coamings, hull
edges, cargo) in one frame, kept in the map frame with their normals. How a frame is
registered to it is a setting (`registration.method`), each seeded with the filter's prediction:
- point_to_plane (the default): a point-to-plane ICP with a Tukey kernel (perception/
  point_to_plane.py: Open3D's iteration on a search index kept while the model is unchanged);
  kiss-icp (its voxel map and point-to-point ICP, C++ through its Python API) runs first only
  when the prior is poor (the first frames, after an outage): it pulls in from metres;
- kiss_icp: kiss-icp's `align_points_to_map` against its voxel map of the model, every frame;
- kiss_icp_refined: kiss_icp, then the point-to-plane ICP from its pose.
On a deck seen from above kiss-icp's point-to-point ICP slides along the structure: every
frame registered by kiss-icp alone is several times worse in y and yaw than point-to-plane's;
refined, it is as good, at several times its registration time (kiss-icp's iterations;
BENCHMARKS.md, "Registration method"). A model grown frame by frame from registered poses
drifts (centimetres in seconds, with either ICP); the keyframe does not, and a new keyframe is
taken only when the old one no longer overlaps.

Frames: `level` is the crane vessel's heading frame as the installation sees it (levelled
with the MRU's roll and pitch, x along the crane's heading, origin at the crane vessel's
reference point); `map` is the feeder frame the model is kept in (fixed to the feeder).

kiss-icp returns a pose and nothing about how well each direction was constrained. A deck
seen from above is nearly a plane, which pins z, roll and pitch and leaves x, y and yaw to
the bulwarks, coamings and cargo; when those are few a direction slides. The information
matrix of the point-to-plane residuals about the solution (normals from the frame itself)
says which: its eigenvectors with small eigenvalues are the directions not to update.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from boomtip.data.poses import inverse, pose_matrix, pose_vector, transform
from boomtip.perception.point_to_plane import Correspondences, Surface, cross_rows, icp_point_to_plane


def _o3d():
    """open3d, imported when a model is built: the settings (RegistrationConfig) are read by
    every user of the processing settings, and open3d and kiss-icp take most of a second to import."""
    import open3d

    return open3d


class RegistrationConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")

    sample_m: float = Field(0.0, ge=0, description="frames are voxel-sampled at this size before the static test and the "
                            "structure (0: every return kept; the keyframe keeps it). At 0.25 m it would keep nearly every "
                            "return of a LiDAR frame and still cost a few ms a frame: the ICP samples its own")
    keyframe_m: float = Field(0.0, ge=0, description="the keyframe's voxel, when coarser than the frames' (0: the frame's)")
    icp_sample_m: float = Field(0.5, gt=0, description="and the frame registered to it at this size: ICP's time goes with the source")
    method: Literal["point_to_plane", "kiss_icp", "kiss_icp_refined"] = Field(
        "point_to_plane", description="how each frame is registered to the model, from the filter's prediction. point_to_plane: "
        "the point-to-plane ICP with a Tukey kernel (perception/point_to_plane.py; kiss-icp only to re-acquire, see "
        "kiss_above_sigma_m). kiss_icp: kiss-icp's align_points_to_map (its point-to-point ICP with a Geman-McClure kernel, "
        "C++) against its voxel map of the model, every frame. kiss_icp_refined: kiss_icp, then the point-to-plane ICP from "
        "its pose. Each method's information matrix is the point-to-plane residuals' about its pose. The model's merges "
        "always use the point-to-plane ICP. kiss_icp is several times worse in y and yaw than point_to_plane; "
        "kiss_icp_refined is as good, at several times its registration time (BENCHMARKS.md)")
    kiss_voxel_m: float = Field(0.5, gt=0, description="kiss-icp's map voxel")
    kiss_above_sigma_m: float = Field(0.15, gt=0, description="kiss-icp runs first when the prior's sigma exceeds this "
                                      "(re-acquisition: correspondences out to 3 sigma, up to 5 m)")
    kiss_max_correspondence_m: float = Field(1.0, gt=0, description="kiss-icp's correspondence distance, every frame "
                                             "(methods kiss_icp and kiss_icp_refined)")
    kiss_kernel_m: float = Field(0.1, gt=0, description="kiss-icp's Geman-McClure kernel scale, every frame (its "
                                 "re-acquisition's ratio: a third of the correspondence distance)")
    max_correspondence_m: float = Field(1.0, gt=0, description="point-to-plane correspondence distance")
    tukey_m: float = Field(0.3, gt=0, description="Tukey kernel width of the point-to-plane residuals")
    merge_tukey_m: float = Field(0.05, ge=0, description="a merge's registrations (the frames to each other, and the first "
                                 "frame, which anchors the map, to the others) are refined from the ICP's pose with this "
                                 "narrower kernel (0: not refined). Correspondences 5-30 cm off the model's surface still "
                                 "pull with the wide kernel and bias a frame by its viewpoint (the first frame, which "
                                 "anchors the map, by about a centimetre); the narrow kernel leaves them out. Not per frame: a "
                                 "second ICP there costs about a quarter more of the frame's time for no gain in accuracy")
    max_iterations: int = Field(30, ge=1, le=1000)
    relative_change: float = Field(1e-4, gt=0, lt=1, description="ICP stops when its fitness and inlier RMSE change by less "
                                   "than this (relative): from the filter's prediction a tighter stop is no more accurate "
                                   "and nearly doubles the ICP's time")
    normal_neighbours: int = Field(10, ge=5, le=100)
    point_sigma_m: float = Field(0.03, gt=0, description="1-sigma point-to-plane residual of a well-matched point")
    info_inflation: float = Field(30.0, ge=1, description="residuals are correlated (one surface, one scan pattern): the "
                                  "information of N points is that of N / this independent ones")
    min_points: int = Field(100, ge=10)
    keyframe_frames: int = Field(1, ge=1, description="frames merged into a keyframe (the first, then each registered one)")
    model_merges: tuple[int, ...] = Field((20, 50, 100, 200), description="when this many frames are registered, they are aligned "
                                          "to each other and become the model; the last is final (empty: the first frame's "
                                          "keyframe stays the model)")
    @field_validator("model_merges")
    @classmethod
    def _merges_ascending(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if any(n < 2 for n in v) or list(v) != sorted(set(v)):
            raise ValueError(f"model_merges must be ascending frame counts of at least 2, got {list(v)}")
        return v

    merge_max_frames: int = Field(50, ge=2, description="a merge aligns and merges at most this many of the frames collected, "
                                  "spread evenly over them (the first, which holds the map frame, among them); the others keep "
                                  "their poses for the next merge. A merge's time goes with the frames it aligns, its gain with "
                                  "the viewpoints they span, which frames spread over the whole collection keep")
    model_iterations: int = Field(1, ge=1, le=10, description="rounds of aligning the model's frames to each other (a second "
                                  "gains little: each merge starts from the last one's poses)")
    merge_lag_frames: tuple[int, ...] = Field((0,), description="0: each merge runs inline (the default: see below). Else "
                                              "each merge (in model_merges' order; past "
                                              "its end, the last lag) runs beside the frames and its model is taken this many "
                                              "LiDAR frames after the one that started it, waiting there if it is not done (so "
                                              "a run never depends on the machine's speed; 0: inline). The early merges matter "
                                              "most: taken ten frames late or more they let the y error grow markedly, two or five "
                                              "frames late hardly. The late ones take seconds (200 frames) and bear long lags: 50 and "
                                              "100 frames late cost no more than 10 and 20. Even short lags cost a little "
                                              "accuracy against inline: inline is the default")

    @field_validator("merge_lag_frames")
    @classmethod
    def _lags_not_negative(cls, v: tuple[int, ...]) -> tuple[int, ...]:
        if any(n < 0 for n in v):
            raise ValueError(f"merge_lag_frames must be frame counts of at least 0, got {list(v)}")
        return v

    model_voxel_m: float = Field(0.25, gt=0, description="the model's voxel")
    min_fitness: float = Field(0.3, gt=0, le=1, description="below this overlap with the keyframe a new keyframe is taken")


@dataclass
class Registration6:
    """One frame registered to the model."""

    T_map_level: np.ndarray  # 4x4: level -> map
    info6: np.ndarray  # 6x6 information of the map frame's pose in the level frame (x, y, z, rotations)
    n_points: int
    fitness: float  # fraction of the frame's points matched in the keyframe
    status: str  # "ok" or why there is no registration
    kiss: bool = False  # kiss-icp registered it first (re-acquisition, or its method)
    source_sampled: np.ndarray | None = None  # the frame as registered (icp_source): its merges register it again


def pose_information(points_level: np.ndarray, normals_level: np.ndarray, origin_level: np.ndarray, sigma_m: float) -> np.ndarray:
    """Information (6x6) of the map frame's pose (x, y, z, and small rotations about the level
    axes through its origin) from point-to-plane residuals n.(p - q): a translation dt changes a
    residual by -n.dt, a rotation dw about the origin by -((p - o) x n).dw."""
    J = np.empty((len(points_level), 6))
    J[:, :3] = normals_level
    cross_rows(points_level - origin_level, normals_level, J[:, 3:])
    return J.T @ J / (sigma_m * sigma_m)


def merged_cloud(frames_level: list[np.ndarray], T_map_level: list[np.ndarray], voxel_m: float, normal_neighbours: int):
    """Frames placed in the map frame, voxel-averaged, with normals: a surface sampled by many
    frames, each on its own part of it."""
    o3d = _o3d()
    pts = np.vstack([transform(T, p) for p, T in zip(frames_level, T_map_level)])
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)).voxel_down_sample(voxel_m)
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(normal_neighbours))
    return cloud


def surface_of(cloud) -> Surface:
    """An Open3D cloud with normals as a surface to register to (its search index built once)."""
    return Surface(np.asarray(cloud.points), np.asarray(cloud.normals))


def icp_source(source_level: np.ndarray, cfg: RegistrationConfig) -> np.ndarray:
    """A frame's points as registered: sampled coarser than the model (ICP's time goes with the source)."""
    if cfg.icp_sample_m <= cfg.sample_m or len(source_level) == 0:
        return source_level
    o3d = _o3d()
    return np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source_level)).voxel_down_sample(cfg.icp_sample_m).points)


def icp_refined(surface: Surface, source_level: np.ndarray, T_guess: np.ndarray, cfg: RegistrationConfig):
    """ICP with the wide kernel (it converges from a pose centimetres off), then refined with
    the merge's narrow one (without the near-miss correspondences)."""
    matcher = Correspondences(surface, source_level, cfg.max_correspondence_m)  # shared: the refinement starts where this ends
    res = icp_point_to_plane(surface, source_level, T_guess, cfg.max_correspondence_m, cfg.tukey_m, cfg.relative_change,
                             cfg.max_iterations, matcher)
    if cfg.merge_tukey_m > 0 and np.all(np.isfinite(res.T)):
        fine = icp_point_to_plane(surface, source_level, res.T, cfg.max_correspondence_m, cfg.merge_tukey_m, cfg.relative_change,
                                  cfg.max_iterations, matcher)
        if np.all(np.isfinite(fine.T)) and len(fine.source_index) >= min(cfg.min_points, len(res.source_index)):
            return fine
    return res  # the refinement lost the frame (a non-finite pose, or moved off the model): the wide fit stands


def align_frames(frames_level: list[np.ndarray], T_map_level: list[np.ndarray], cfg: RegistrationConfig,
                 samples_level: list[np.ndarray | None] | None = None) -> list[np.ndarray]:
    """The frames' poses made consistent with each other: each frame registered to the merged
    cloud of the other half (even frames to the odd ones' and back: a frame in its own model
    matches itself and would not move); the first frame holds the map frame and does not move.

    One frame's keyframe is sampled at the LiDAR's spacing (35-50 cm at 40-70 m for 0.5 deg):
    each point's normal spans the edges of bulwarks and coamings, and a frame seen from another
    height matches its points to the wrong side of an edge. The registrations to it are then
    off by a function of the viewpoint (centimetres in y, following the feeder's height);
    registrations to frames merged from many viewpoints are off by millimetres.

    `samples_level`: each frame as sampled for ICP (icp_source), where known (None: sampled here)."""
    samples = [s if s is not None else icp_source(f, cfg) for f, s in zip(frames_level, samples_level or [None] * len(frames_level))]

    def register(i: int, model: Surface) -> np.ndarray:
        res = icp_refined(model, samples[i], poses[i], cfg)
        ok = np.all(np.isfinite(res.T)) and len(res.source_index) >= cfg.min_points
        return res.T.copy() if ok else poses[i]

    poses = [T.copy() for T in T_map_level]
    halves = (list(range(0, len(poses), 2)), list(range(1, len(poses), 2)))
    for _ in range(cfg.model_iterations):
        for target, moving in ((halves[0], halves[1]), (halves[1], halves[0])):
            model = surface_of(merged_cloud([frames_level[i] for i in target], [poses[i] for i in target],
                                            cfg.model_voxel_m, cfg.normal_neighbours))
            for i in moving:
                poses[i] = register(i, model)
    # The frames were placed by the filter (against a young model, or dead-reckoned while x and y
    # wait for one), with an offset they share: aligned to each other they keep it. The first
    # frame defines the map frame: where it registers to the others is where they must be moved to.
    others = surface_of(merged_cloud(frames_level[1:], poses[1:], cfg.model_voxel_m, cfg.normal_neighbours))
    T0 = T_map_level[0]
    fit0 = register(0, others)
    M = T0 @ inverse(fit0)
    return [T0] + [M @ T for T in poses[1:]]


@dataclass
class MergedModel:
    """A merge's result: the frames' poses aligned, their merged cloud and its search index."""

    frames: int  # the first this many collected frames
    poses: list[np.ndarray]
    cloud: object  # an Open3D cloud with normals, in the map frame
    surface: Surface

    def __getstate__(self) -> dict:
        """As arrays (a merge made in another process comes back pickled): the cloud and its
        search index are rebuilt from its points and normals, the same ones."""
        return {"frames": self.frames, "poses": self.poses, "points": np.asarray(self.cloud.points),
                "normals": np.asarray(self.cloud.normals)}

    def __setstate__(self, state: dict) -> None:
        o3d = _o3d()
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(state["points"]))
        cloud.normals = o3d.utility.Vector3dVector(state["normals"])
        self.frames, self.poses, self.cloud, self.surface = state["frames"], state["poses"], cloud, surface_of(cloud)


def merge_choice(frames: int, max_frames: int) -> np.ndarray:
    """Which of `frames` collected frames a merge aligns: all of them up to `max_frames`, else
    that many spread evenly from the first (which holds the map frame) to the last."""
    if frames <= max_frames:
        return np.arange(frames)
    return np.unique(np.round(np.linspace(0.0, frames - 1.0, max_frames)).astype(np.int64))


def merged_model(frames_level: list[np.ndarray], T_map_level: list[np.ndarray], cfg: RegistrationConfig,
                 samples_level: list[np.ndarray | None] | None = None) -> MergedModel:
    """The frames (at most `cfg.merge_max_frames` of them, merge_choice) aligned to each other
    and merged into a model (a pure function of its inputs: it may run beside the frames, see
    perception/feeder_merges.py); the frames not chosen keep their poses. `samples_level`: the
    frames as sampled for ICP, where known."""
    chosen = merge_choice(len(frames_level), cfg.merge_max_frames)
    samples = samples_level or [None] * len(frames_level)
    aligned = align_frames([frames_level[i] for i in chosen], [T_map_level[i] for i in chosen], cfg,
                           [samples[i] for i in chosen])
    cloud = merged_cloud([frames_level[i] for i in chosen], aligned, cfg.model_voxel_m, cfg.normal_neighbours)
    poses = list(T_map_level)
    for i, T in zip(chosen, aligned):
        poses[i] = T
    return MergedModel(len(frames_level), poses, cloud, surface_of(cloud))


class FeederModel:
    """The feeder's model (map frame) and the registrations to it: the first frame's keyframe,
    then the first frames aligned to each other and merged, at each of `model_merges` frames."""

    def __init__(self, cfg: RegistrationConfig | None = None) -> None:
        from kiss_icp.mapping import VoxelHashMap
        from kiss_icp.registration import Registration

        self.cfg = cfg or RegistrationConfig()
        self.keyframe = None  # an Open3D cloud with normals, in the map frame
        self.surface: Surface | None = None  # the keyframe with its search index
        self.kiss_map = VoxelHashMap(self.cfg.kiss_voxel_m, 1e4, 20)
        self.kiss = Registration(max_num_iterations=100, convergence_criterion=1e-4, max_num_threads=0)
        self.keyframes = 0
        # (frame, level frame; its pose; the frame as sampled for ICP, None until known) for the model
        self.collected: list[tuple[np.ndarray, np.ndarray, np.ndarray | None]] = []
        self.merged = False
        self.model_frames = 1  # frames the model was merged from (the first keyframe: one)

    def _use(self, cloud) -> None:
        """The model becomes this cloud (with normals): it and its search index are kept until it changes."""
        self.keyframe = cloud
        self.surface = surface_of(cloud)

    @property
    def empty(self) -> bool:
        return self.keyframe is None

    def set_keyframe(self, source_level: np.ndarray, T_map_level: np.ndarray) -> None:
        """The model is this frame's returns, placed in the map frame by the filter's pose."""
        pts_map = transform(T_map_level, source_level)
        kf = _o3d().geometry.PointCloud(_o3d().utility.Vector3dVector(pts_map))
        if self.cfg.keyframe_m > self.cfg.sample_m:
            kf = kf.voxel_down_sample(self.cfg.keyframe_m)
            pts_map = np.asarray(kf.points)
        kf.estimate_normals(_o3d().geometry.KDTreeSearchParamKNN(self.cfg.normal_neighbours))
        self._use(kf)
        self.kiss_map.clear()
        self.kiss_map.add_points(pts_map)
        self.keyframes += 1
        self.keyframe_size = 1
        # a new keyframe is a new model: it grows and merges again from this frame (and a
        # registration's x and y wait for it as they did for the first)
        self.collected = [(source_level, T_map_level, None)]
        self.merged = False
        self.model_frames = 1

    def collect(self, source_level: np.ndarray, T_map_level: np.ndarray, sample_level: np.ndarray | None = None) -> bool:
        """Keep a registered frame for the model (`sample_level`: as its registration sampled it,
        which every merge registers again); True when it is time to merge."""
        if self.merged or not self.cfg.model_merges:
            return False
        self.collected.append((source_level, T_map_level, sample_level))
        return len(self.collected) in self.cfg.model_merges

    def merge_inputs(self) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """What a merge needs, as of now: the collected frames, their poses and their ICP samples
        (new lists, so that frames collected while the merge runs elsewhere do not enter it). A
        frame's sample is made once, here, when its registration did not hand it over."""
        for i, (f, T, sample) in enumerate(self.collected):
            if sample is None:
                self.collected[i] = (f, T, icp_source(f, self.cfg))
        return [f for f, _, _ in self.collected], [T for _, T, _ in self.collected], [s for _, _, s in self.collected]

    def merge(self) -> list[np.ndarray]:
        """The collected frames aligned to each other (the first is the keyframe's and holds
        the map frame) become the model. Returns their poses as aligned."""
        frames, poses, samples = self.merge_inputs()
        merged = merged_model(frames, poses, self.cfg, samples)
        self.apply_merge(merged)
        return merged.poses

    def apply_merge(self, merged: "MergedModel") -> None:
        """The model becomes a merge's (computed from the first `merged.frames` collected
        frames); frames collected since follow the merged ones with the poses they had."""
        n = merged.frames
        self.keyframe, self.surface = merged.cloud, merged.surface
        self.kiss_map.clear()
        self.kiss_map.add_points(np.asarray(self.keyframe.points))
        # the next merge starts from these poses
        self.collected = [(f, T, s) for (f, _, s), T in zip(self.collected[:n], merged.poses)] + self.collected[n:]
        self.model_frames = n
        if n >= max(self.cfg.model_merges):
            self.collected.clear()
            self.merged = True

    def extend_keyframe(self, source_level: np.ndarray, T_map_level: np.ndarray) -> None:
        """Add a registered frame to the keyframe: the scan pattern falls elsewhere on the
        structure each frame, so a few frames fill the edges one frame leaves ragged."""
        pts = np.vstack([np.asarray(self.keyframe.points), transform(T_map_level, source_level)])
        kf = _o3d().geometry.PointCloud(_o3d().utility.Vector3dVector(pts)).voxel_down_sample((self.cfg.sample_m or self.cfg.model_voxel_m) * 0.5)
        kf.estimate_normals(_o3d().geometry.KDTreeSearchParamKNN(self.cfg.normal_neighbours))
        self._use(kf)
        self.kiss_map.add_points(transform(T_map_level, source_level))

    def register(self, source_level: np.ndarray, T_map_level_guess: np.ndarray, prior_sigma_m: float) -> Registration6:
        """Align a sampled frame (level frame) to the keyframe from the guess."""
        cfg = self.cfg
        n = len(source_level)
        if n < cfg.min_points:
            return Registration6(T_map_level_guess, np.zeros((6, 6)), n, 0.0, f"too few feeder points above the deck ({n} < {cfg.min_points})")
        if self.keyframe is None:
            return Registration6(T_map_level_guess, np.zeros((6, 6)), n, 0.0, "no model yet")
        guess, kiss = T_map_level_guess, False
        if prior_sigma_m > cfg.kiss_above_sigma_m:
            dist = float(min(3.0 * prior_sigma_m, 5.0))
            guess = self.kiss.align_points_to_map(source_level, self.kiss_map, T_map_level_guess, dist, dist / 3.0)
            kiss = True
        source_level = icp_source(source_level, cfg)
        sampled = source_level
        if cfg.method != "point_to_plane":
            guess = self.kiss.align_points_to_map(source_level, self.kiss_map, guess, cfg.kiss_max_correspondence_m, cfg.kiss_kernel_m)
            kiss = True
        # kiss_icp: no point-to-plane iteration, only its correspondences about kiss-icp's pose (for the information)
        iterations = 0 if cfg.method == "kiss_icp" else cfg.max_iterations
        res = icp_point_to_plane(self.surface, source_level, guess, cfg.max_correspondence_m, cfg.tukey_m,
                                 cfg.relative_change, iterations)
        T = res.T
        if not np.all(np.isfinite(T)) or len(res.source_index) < cfg.min_points:
            return Registration6(T_map_level_guess, np.zeros((6, 6)), n, res.fitness, "registration found no overlap", kiss)
        T_level_map = inverse(T)
        normals_level = self.surface.normals.take(res.surface_index, axis=0) @ T_level_map[:3, :3].T
        info = pose_information(source_level.take(res.source_index, axis=0), normals_level, T_level_map[:3, 3], cfg.point_sigma_m)
        return Registration6(T.copy(), info / cfg.info_inflation, n, res.fitness, "ok", kiss, sampled)
