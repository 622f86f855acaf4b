"""A LiDAR beam's footprint: a real beam diverges, so near a depth edge its light falls on two
surfaces at once and the sensor reports a mix of the two (a "mixed pixel") or, farther apart,
the return its mode keeps (the strongest, the first, the last, or first and last: dual).

Casting every ray's footprint would multiply the cast by the footprint's samples. A footprint
(a few mrad) is narrower than the scan's step (the grid's 0.5 deg is 8.7 mrad), so it can only
straddle an edge that also lies between the ray and a neighbour: those rays (`edge_rays`, from
the centre rays' ranges) are the only ones whose footprint is cast.

The beam is Gaussian; `divergence_mrad` is its full angle at 1/e^2 (data sheets'). Its power is
sampled by a centre ray and a ring of `RING_RAYS` at `RING_RADIUS` of the 1/e^2 radius, weighted
by the power of the disc and annulus they stand for (the centre's disc out to 0.35 of the
radius holds 22 % of the power, the annulus to the radius 65 %; the 13 % beyond is left out and
the weights renormalised).
"""

from __future__ import annotations

import numpy as np

from boomtip.data.sim.raycast import Hits

RING_RAYS = 6
RING_RADIUS = 0.65  # of the 1/e^2 radius: the annulus' power-weighted middle
CENTRE_WEIGHT = 0.217 / 0.865
RING_WEIGHT = (1.0 - CENTRE_WEIGHT) / RING_RAYS
EDGE_CURVATURE_M = 0.05  # a range's second difference beyond this between neighbours: a depth edge (a
# plane's at 50 m with the grid's step: 0.03 m at 60 deg incidence; more grazing rays are cast too, a few)


def sample_weights() -> np.ndarray:
    """(S,) the centre's weight, then the ring's."""
    return np.r_[CENTRE_WEIGHT, np.full(RING_RAYS, RING_WEIGHT)]


def footprint_dirs(dirs: np.ndarray, divergence_mrad: float) -> np.ndarray:
    """(N,S,3) unit directions sampling each ray's footprint (N,3 unit): the ray itself, then the
    ring around it (in the plane normal to the ray)."""
    d = np.asarray(dirs, float)
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(d, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(d, e1)
    phi = np.arange(RING_RAYS) * (2 * np.pi / RING_RAYS)
    tan_rho = np.tan(RING_RADIUS * 0.5e-3 * divergence_mrad)
    ring = d[:, None, :] + tan_rho * (np.cos(phi)[None, :, None] * e1[:, None, :] + np.sin(phi)[None, :, None] * e2[:, None, :])
    ring /= np.linalg.norm(ring, axis=2, keepdims=True)
    return np.concatenate([d[:, None, :], ring], axis=1)


def edge_rays(range_grid_m: np.ndarray, wrap_first_axis: bool) -> np.ndarray:
    """(A,E) which rays of a scan (ranges on its azimuth x elevation grid, inf on a miss) lie at
    a depth edge: a range whose second difference along either axis passes EDGE_CURVATURE_M, or
    a hit beside a miss. A spinning sensor's azimuths wrap around (`wrap_first_axis`); at the
    ends of an axis that does not, a ray takes its neighbour's second difference."""
    hit = np.isfinite(range_grid_m)
    r = np.where(hit, range_grid_m, 0.0).astype(float)
    edge = np.zeros(r.shape, bool)
    for axis in (0, 1):
        rr, hh = np.moveaxis(r, axis, 0), np.moveaxis(hit, axis, 0)
        if len(rr) < 3:
            continue
        if axis == 0 and wrap_first_axis:
            rr, hh = np.concatenate([rr[-1:], rr, rr[:1]]), np.concatenate([hh[-1:], hh, hh[:1]])
        curved = (np.abs(rr[:-2] - 2.0 * rr[1:-1] + rr[2:]) > EDGE_CURVATURE_M) & hh[:-2] & hh[1:-1] & hh[2:]
        step = hh[1:] != hh[:-1]  # a hit beside a miss: both rays
        if axis == 0 and wrap_first_axis:
            marked = step[:-1] | step[1:]
        else:
            curved = np.concatenate([curved[:1], curved, curved[-1:]])
            marked = np.zeros(hh.shape, bool)
            marked[:-1] |= step
            marked[1:] |= step
        edge |= np.moveaxis(curved | marked, 0, axis)
    return edge


def mixed_returns(range_m: np.ndarray, energy: np.ndarray, separation_m: float, mode: str):
    """What a sensor reports of each footprint's sub-returns: ranges (N,S), inf on a miss, and
    their energies at the sensor (N,S; weight x reflectivity x cos incidence / range^2, 0 on a
    miss). Sub-returns nearer each other than `separation_m` (the pulse's extent: the sensor
    cannot tell them apart) merge into one return at their energy-weighted range; of separate
    returns `mode` keeps the strongest, the first or the last; dual keeps the first and the
    last. Returns (range (N,), the sample dominating it (N,), energy (N,)) of the primary
    return (inf range where every sample missed) and a mask (N,) with (range, sample, energy)
    of the second return of a dual footprint (where it has two)."""
    n, s = range_m.shape
    order = np.argsort(range_m, axis=1, kind="stable")
    r = np.take_along_axis(range_m, order, axis=1)
    e = np.take_along_axis(energy, order, axis=1)
    hit = np.isfinite(r)
    gap = np.zeros((n, s), bool)
    gap[:, 1:] = (np.diff(np.where(hit, r, 0.0), axis=1) > separation_m) & hit[:, 1:]
    group = np.cumsum(gap, axis=1)  # per row, 0.. in range order; misses last, in the last group (energy 0)
    flat = (np.arange(n)[:, None] * s + group).ravel()
    e_hit = np.where(hit, e, 0.0)
    g_energy = np.bincount(flat, e_hit.ravel(), n * s).reshape(n, s)
    g_range = np.bincount(flat, (e_hit * np.where(hit, r, 0.0)).ravel(), n * s).reshape(n, s)
    g_count = np.bincount(flat, hit.ravel().astype(float), n * s).reshape(n, s)
    g_range = np.divide(g_range, g_energy, out=np.full((n, s), np.inf), where=g_energy > 0)
    # a group of hits with no energy (black surfaces) still has a range: its samples' mean
    plain = np.bincount(flat, np.where(hit, r, 0.0).ravel(), n * s).reshape(n, s)
    dark = (g_energy <= 0) & (g_count > 0)
    g_range[dark] = plain[dark] / g_count[dark]
    # the sample carrying most of a group's energy names its surface
    e_rank = np.where(hit, e, -1.0)
    g_best = np.full((n, s), -1)
    best_e = np.full((n, s), -np.inf)
    for j in range(s):  # S (7) columns: a loop over the samples, not over rays
        better = e_rank[:, j] > best_e[np.arange(n), group[:, j]]
        rows = np.flatnonzero(better)
        best_e[rows, group[rows, j]] = e_rank[rows, j]
        g_best[rows, group[rows, j]] = order[rows, j]
    present = g_count > 0
    n_groups = present.sum(axis=1)
    last = np.maximum(n_groups - 1, 0)
    if mode == "first" or mode == "dual":
        pick = np.zeros(n, int)
    elif mode == "last":
        pick = last
    else:
        pick = np.argmax(np.where(present, g_energy, -1.0), axis=1)
    rows = np.arange(n)
    primary = (g_range[rows, pick], g_best[rows, pick], g_energy[rows, pick])
    second_mask = (n_groups > 1) if mode == "dual" else np.zeros(n, bool)
    second = (g_range[rows, last], g_best[rows, last], g_energy[rows, last])
    no_hit = n_groups == 0
    primary[0][no_hit] = np.inf
    return primary, second_mask, second


def cast_footprints(caster, faces, fans, hits, R_world_sensor: np.ndarray, p_world_sensor: np.ndarray,
                    R_world_body, p_world_body, scale_body, divergence_mrad: float, separation_m: float,
                    mode: str, retro_gain: float, wrap_azimuth: bool):
    """The scan's hits (`Hits` of its centre rays, cast as fans at M = 1 or one pose per fan)
    with the footprints of its edge rays cast and mixed (`mixed_returns`), and the dual mode's
    second returns as (ray index, range, flat face, cos incidence). A mixed return keeps the
    face of the sample that dominates it, and a cosine that gives it the footprint's energy."""
    n_az, n_el = len(fans.az_rad), len(fans.el_rad)
    rays = np.flatnonzero(edge_rays(hits.range_m.reshape(n_az, n_el), wrap_azimuth).ravel())
    if len(rays) == 0:
        return hits, (np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.int64), np.zeros(0))
    ring_sensor = footprint_dirs(fans.dirs[rays], divergence_mrad)[:, 1:]  # (N,S-1,3): the centre is the ray, cast already
    pose = np.zeros(len(rays), np.int64) if len(R_world_sensor) == 1 else rays // n_el
    if len(R_world_sensor) == 1:
        ring_world = ring_sensor.reshape(-1, 3) @ R_world_sensor[0].T
    else:
        ring_world = np.einsum("nij,nsj->nsi", R_world_sensor[pose], ring_sensor).reshape(-1, 3)
    ring = caster.cast(np.repeat(p_world_sensor[pose], RING_RAYS, axis=0), ring_world, R_world_body, p_world_body,
                       pose_index=None if len(R_world_sensor) == 1 else np.repeat(pose, RING_RAYS), scale_body=scale_body)
    flat_face = _flat_faces(hits, faces)
    # each footprint's samples: the ray's own hit, then its ring's
    r_sub = np.column_stack([hits.range_m[rays].astype(float), ring.range_m.reshape(-1, RING_RAYS)])
    faces_sub = np.column_stack([flat_face[rays], _flat_faces(ring, faces).reshape(-1, RING_RAYS)])
    cos_sub = np.maximum(np.column_stack([hits.cos_incidence[rays], ring.cos_incidence.reshape(-1, RING_RAYS)])
                         .astype(float), 1e-3)
    hit_sub = np.isfinite(r_sub)
    refl = faces.reflectivity[faces_sub] * np.where(faces.retro[faces_sub], retro_gain, 1.0)
    energy = np.where(hit_sub, sample_weights()[None, :] * refl * cos_sub / np.where(hit_sub, r_sub, 1.0) ** 2, 0.0)
    (r1, j1, e1), dual, (r2, j2, e2) = mixed_returns(r_sub, energy, separation_m, mode)
    row = np.arange(len(rays))

    def surface(rows, r, j, e):
        """The flat face and the effective cosine of returns whose dominant sample is j."""
        jj = np.maximum(j, 0)
        f, own_cos = faces_sub[rows, jj], cos_sub[rows, jj]
        base = faces.reflectivity[f] * np.where(faces.retro[f], retro_gain, 1.0)
        eff = np.divide(e * np.where(np.isfinite(r), r, 0.0) ** 2, base, out=own_cos.copy(), where=base > 0)
        return f, np.where(faces.retro[f], own_cos, eff)  # (a retro-reflector's lobe needs its true angle)

    f1, c1 = surface(row, r1, j1, e1)
    seen = np.isfinite(r1)
    range_m = hits.range_m.copy()
    range_m[rays] = r1.astype(range_m.dtype)
    flat = flat_face.copy()
    flat[rays] = np.where(seen, f1, flat[rays])
    cos_inc = hits.cos_incidence.copy()
    cos_inc[rays] = np.where(seen, c1, 0.0).astype(cos_inc.dtype)
    mixed = Hits(range_m, None, None, cos_inc, flat_face=flat.astype(np.int32), face_offset=caster.face_offset)
    f2, c2 = surface(row[dual], r2[dual], j2[dual], e2[dual])
    return mixed, (rays[dual], r2[dual], f2, c2)


def _flat_faces(hits, faces) -> np.ndarray:
    """(K,) int64: each hit's face over all bodies (the materials' index; 0 on a miss)."""
    if hits.flat_face is not None:
        return np.where(hits.hit, hits.flat_face, 0).astype(np.int64)
    flat = np.zeros(len(hits.range_m), np.int64)
    flat[hits.hit] = faces.flat(hits, hits.hit)
    return flat


def with_second_returns(idx, r, cos_inc, intensity, label, second, faces, lo, hi):
    """The returns and a dual-return footprint's second returns (ray index, range, flat face,
    cos incidence) in range, in ray order (a ray's two in range order)."""
    rays, r2, f2, c2 = second
    ok = (r2 >= lo) & (r2 <= hi)
    rays, r2, f2, c2 = rays[ok], r2[ok], f2[ok], c2[ok]
    order = np.lexsort((np.concatenate([r, r2]), np.concatenate([idx, rays])))
    return (np.concatenate([idx, rays]).take(order), np.concatenate([r, r2.astype(r.dtype)]).take(order),
            np.concatenate([cos_inc, np.maximum(c2, 1e-3).astype(cos_inc.dtype)]).take(order),
            np.concatenate([intensity, (faces.reflectivity_signed[f2] * c2).astype(intensity.dtype)]).take(order),
            np.concatenate([label, faces.label[f2]]).take(order))


def thinned_returns(second, face_offset: np.ndarray, sea_body: int | None, sea_probability: float,
                    dropout_probability: float, rng: np.random.Generator):
    """The second returns (ray index, range, flat face, cos incidence) the sea's clutter and the
    sensor's dropouts leave, drawn as for the first returns."""
    rays, r2, f2, c2 = second
    keep = np.ones(len(rays), dtype=bool)
    if sea_body is not None:  # only a fraction of the sea's returns come back
        keep &= (np.searchsorted(face_offset, f2, side="right") - 1 != sea_body) | (rng.random(len(rays)) < sea_probability)
    if dropout_probability > 0:
        keep &= rng.random(len(rays)) >= dropout_probability
    return rays[keep], r2[keep], f2[keep], c2[keep]
