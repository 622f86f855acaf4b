"""The hook chain's per-frame rows, kept on disk while the run goes on: a 700 s run has 14,000
LiDAR frames, which in memory (a dict of Python objects per frame, tens of MB; even typed columns,
megabytes) would grow with the run. Each frame's numbers are one float64
record in an unnamed temporary file, appended a chunk of frames at a time; a column is read back
a chunk of records at a time."""

from __future__ import annotations

import math

import numpy as np

from boomtip.data.io.blocks import DiskBlocks
from boomtip.data.meshes import Label
from boomtip.fusion.records import Records
from boomtip.perception.hook import HookDetection, segmentation_scores
from boomtip.perception.rope import RopeFix

__all__ = ["FrameRows", "COLUMNS", "DiskTable", "ROW_DEFAULTS", "frame_row", "fill_prediction", "fill_rope", "fill_block",
           "fill_scores"]

FLOAT = ("t", "x", "y", "z", "sigma_x_m", "sigma_y_m", "sigma_z_m", "fit_rms_m", "precision", "recall", "pred_x",
         "pred_y", "pred_z", "pred_sigma_across_m", "rope_ux", "rope_uy", "rope_uz", "rope_sigma_across_m",
         "rope_radius_m", "rope_precision", "time_ms")
INT = ("n_points", "hook_points_true", "rope_points")
BOOL = ("tracker_accepted", "rope_accepted")
TEXT = ("status", "rope_status")
# hook_measurements.csv's order
COLUMNS = ("t", "status", "x", "y", "z", "sigma_x_m", "sigma_y_m", "sigma_z_m", "n_points", "fit_rms_m", "precision",
           "recall", "hook_points_true", "tracker_accepted", "pred_x", "pred_y", "pred_z", "pred_sigma_across_m",
           "rope_status", "rope_points", "rope_ux", "rope_uy", "rope_uz", "rope_sigma_across_m", "rope_radius_m",
           "rope_accepted", "rope_precision", "time_ms")
_NAN9 = (float("nan"),) * 9
NUMERIC = FLOAT + INT + BOOL  # a record: these, then the fix covariance (9), the rope direction (3) and its covariance (9)
_AT = {k: i for i, k in enumerate(NUMERIC)}
COV, ROPE_DIR, ROPE_COV = slice(len(NUMERIC), len(NUMERIC) + 9), slice(len(NUMERIC) + 9, len(NUMERIC) + 12), \
    slice(len(NUMERIC) + 12, len(NUMERIC) + 21)
RECORD = len(NUMERIC) + 21
CHUNK = 1024  # records buffered before a write, and read back at a time
ROW_DEFAULTS = {"x": np.nan, "y": np.nan, "z": np.nan, "sigma_x_m": np.nan, "sigma_y_m": np.nan, "sigma_z_m": np.nan,
                "n_points": 0, "fit_rms_m": np.nan, "precision": np.nan, "recall": np.nan, "hook_points_true": 0,
                "tracker_accepted": False, "pred_x": np.nan, "pred_y": np.nan, "pred_z": np.nan,
                "pred_sigma_across_m": np.nan, "rope_status": "", "rope_points": 0, "rope_ux": np.nan,
                "rope_uy": np.nan, "rope_uz": np.nan, "rope_sigma_across_m": np.nan, "rope_accepted": False,
                "rope_precision": np.nan, "rope_radius_m": np.nan}


def frame_row(t_s: float) -> dict:
    """A frame's row before anything is known of it."""
    return {"t": t_s, **ROW_DEFAULTS}


def fill_prediction(row: dict, p_pred: np.ndarray, sigma_across_m: float) -> None:
    row["pred_x"], row["pred_y"], row["pred_z"] = p_pred
    row["pred_sigma_across_m"] = sigma_across_m


def fill_rope(row: dict, rope: RopeFix, hoist_m: float) -> None:
    row["rope_status"], row["rope_points"] = rope.status, rope.n_points
    if rope.ok:
        row["rope_ux"], row["rope_uy"], row["rope_uz"] = rope.direction
        row["rope_radius_m"] = rope.radius_m
        row["rope_sigma_across_m"] = hoist_m * math.sqrt(float(np.linalg.eigvalsh(rope.cov)[-1]))


def fill_block(row: dict, det: HookDetection, cov_m2: np.ndarray) -> None:
    row["status"], row["n_points"], row["fit_rms_m"] = det.status, det.n_points, det.fit_rms_m
    if det.has_fix:
        row["x"], row["y"], row["z"] = det.position_m
        row["sigma_x_m"], row["sigma_y_m"], row["sigma_z_m"] = np.sqrt(np.diag(cov_m2))


def fill_scores(row: dict, det: HookDetection, rope: RopeFix | None, labels: np.ndarray | None) -> None:
    """The segmentation's precision and recall against the per-point truth labels, which only
    simulated recordings carry (scoring, never an input)."""
    if labels is None:
        return
    row["precision"], row["recall"] = segmentation_scores(det.points_mask, labels)
    row["hook_points_true"] = int(np.count_nonzero(labels == Label.HOOK))
    if rope is not None and rope.ok:
        row["rope_precision"] = float(np.mean(labels[rope.mask] == Label.ROPE))


class FrameRows:
    """Rows (dicts with the keys of :data:`COLUMNS`) appended one per frame, kept as records on
    disk (integers and booleans as float64: exact below 2**53), with each frame's fix covariance
    and rope direction and covariance (NaN when none). The text columns stay in memory (a
    reference per frame to a few shared strings)."""

    def __init__(self) -> None:
        self._store = DiskBlocks("boomtip-rows-")  # closed with the rows, however they end
        self._records = Records(RECORD, self._store, CHUNK)
        self._rec = np.empty(RECORD)  # the row being made (Records keeps a copy)
        self._text: dict[str, list[str]] = {k: [] for k in TEXT}

    def append(self, row: dict, cov_m2: np.ndarray, rope_direction: np.ndarray | None,
               rope_cov: np.ndarray | None) -> None:
        rec = self._rec
        rec[:len(NUMERIC)] = [float(row[k]) for k in NUMERIC]
        rec[COV] = np.asarray(cov_m2, float).ravel()
        rec[ROPE_DIR] = _NAN9[:3] if rope_direction is None else np.asarray(rope_direction, float)
        rec[ROPE_COV] = _NAN9 if rope_cov is None else np.asarray(rope_cov, float).ravel()
        for k in TEXT:
            self._text[k].append(str(row[k]))
        self._records.append(rec)

    def __len__(self) -> int:
        return len(self._records)

    def __getitem__(self, name: str) -> np.ndarray:
        """A column: float64, int64, bool, or an object array of str."""
        if name in TEXT:
            return np.array(self._text[name], dtype=object)
        col = self._records.column(_AT[name])
        return col.astype(np.int64) if name in INT else col.astype(bool) if name in BOOL else col

    def xyz(self, prefix: str = "") -> np.ndarray:
        """(N, 3) of the columns ``{prefix}x``, ``{prefix}y``, ``{prefix}z``."""
        return self._records.column([_AT[f"{prefix}{a}"] for a in "xyz"])

    @property
    def cov_m2(self) -> np.ndarray:
        return self._records.column(COV).reshape(-1, 3, 3)

    @property
    def rope_direction(self) -> np.ndarray:
        return self._records.column(ROPE_DIR)

    @property
    def rope_cov(self) -> np.ndarray:
        return self._records.column(ROPE_COV).reshape(-1, 3, 3)

    def text(self, name: str) -> list[str]:
        return list(self._text[name])

    def row(self, i: int) -> dict:
        """Frame i as the dict it was appended as (values as Python scalars)."""
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError(i)
        vals = self._records.read(i, i + 1)[0].tolist()
        out = {k: vals[_AT[k]] for k in FLOAT}
        out.update({k: int(vals[_AT[k]]) for k in INT})
        out.update({k: bool(vals[_AT[k]]) for k in BOOL})
        out.update({k: self._text[k][i] for k in TEXT})
        return out

    def close(self) -> None:
        self._store.close()


class DiskTable:
    """A float64 table (N, k) in an unnamed temporary file, read back by row slices: the chain's
    encoder and MRU tables, which in memory would hold a 700 s run's 6 MB for the whole run. Slicing
    gives an array, so the tracker takes this or an array alike."""

    def __init__(self, table: np.ndarray) -> None:
        table = np.asarray(table, float)
        self.shape = table.shape
        self._blocks = DiskBlocks("boomtip-table-")
        flat = table.reshape(len(table), -1)
        for a in range(0, len(table), CHUNK * 8):
            self._blocks.write(flat[a:a + CHUNK * 8])

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, rows: slice) -> np.ndarray:
        if not isinstance(rows, slice) or rows.step not in (None, 1):
            raise TypeError("a DiskTable reads contiguous row slices only")
        a, b, _ = rows.indices(len(self))
        return self._blocks.read(a, max(a, b)).reshape((-1, *self.shape[1:]))

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        whole = self[:]
        return whole if dtype is None else whole.astype(dtype)

    def close(self) -> None:
        self._blocks.close()
