"""The hook chain's per-frame rows held as columns: a 700 s run has 14,000 LiDAR frames, and a
dict of Python objects per frame took about 2.3 kB (33 MB), the columns about 0.4 kB."""

from __future__ import annotations

from array import array

import numpy as np

__all__ = ["FrameRows", "COLUMNS"]

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


class FrameRows:
    """Rows (dicts with the keys of :data:`COLUMNS`) appended one per frame, kept as typed columns,
    with each frame's fix covariance and rope direction and covariance (NaN when none)."""

    def __init__(self) -> None:
        self._cols: dict[str, array | list] = {k: array("d") for k in FLOAT}
        self._cols.update({k: array("q") for k in INT})
        self._cols.update({k: array("b") for k in BOOL})
        self._cols.update({k: [] for k in TEXT})
        self._cov, self._rope_dir, self._rope_cov = array("d"), array("d"), array("d")

    def append(self, row: dict, cov_m2: np.ndarray, rope_direction: np.ndarray | None,
               rope_cov: np.ndarray | None) -> None:
        for k in FLOAT:
            self._cols[k].append(float(row[k]))
        for k in INT:
            self._cols[k].append(int(row[k]))
        for k in BOOL:
            self._cols[k].append(bool(row[k]))
        for k in TEXT:
            self._cols[k].append(str(row[k]))
        self._cov.extend(np.asarray(cov_m2, float).ravel().tolist())
        self._rope_dir.extend(_NAN9[:3] if rope_direction is None else np.asarray(rope_direction, float).tolist())
        self._rope_cov.extend(_NAN9 if rope_cov is None else np.asarray(rope_cov, float).ravel().tolist())

    def __len__(self) -> int:
        return len(self._cols["t"])

    def __getitem__(self, name: str) -> np.ndarray:
        """A column: float64, int64, bool, or an object array of str."""
        col = self._cols[name]
        if name in TEXT:
            return np.array(col, dtype=object)
        dtype = np.float64 if name in FLOAT else np.int64 if name in INT else np.int8
        # copies: a view would stop the column from growing (an array exporting its buffer)
        out = np.frombuffer(col, dtype=dtype) if len(col) else np.zeros(0, dtype)
        return out.astype(bool) if name in BOOL else out.copy()

    def xyz(self, prefix: str = "") -> np.ndarray:
        """(N, 3) of the columns ``{prefix}x``, ``{prefix}y``, ``{prefix}z``."""
        return np.column_stack([self[f"{prefix}{a}"] for a in "xyz"]) if len(self) else np.zeros((0, 3))

    @property
    def cov_m2(self) -> np.ndarray:
        return np.frombuffer(self._cov, np.float64).reshape(-1, 3, 3).copy() if len(self) else np.zeros((0, 3, 3))

    @property
    def rope_direction(self) -> np.ndarray:
        return np.frombuffer(self._rope_dir, np.float64).reshape(-1, 3).copy() if len(self) else np.zeros((0, 3))

    @property
    def rope_cov(self) -> np.ndarray:
        return np.frombuffer(self._rope_cov, np.float64).reshape(-1, 3, 3).copy() if len(self) else np.zeros((0, 3, 3))

    def text(self, name: str) -> list[str]:
        return list(self._cols[name])

    def row(self, i: int) -> dict:
        """Frame i as the dict it was appended as (values as Python scalars)."""
        return {k: (col[i] if k not in BOOL else bool(col[i])) for k, col in self._cols.items()}
