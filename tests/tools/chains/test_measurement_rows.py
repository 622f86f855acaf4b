import math

from boomtip.data.io.blocks import DiskBlocks
from boomtip.perception.pipeline import Measurement
from boomtip.tools.chains.measurement_rows import MeasurementRows


def _rows(n: int) -> list[Measurement]:
    methods = ("deck_lidar", "reflectors_lidar", "doppler_radar")
    return [Measurement(0.05 * i, methods[i % 3], "D_dot" if i % 3 == 2 else "D", 40.0 + 1e-3 * i if i % 7 else math.nan,
                        1e-3 * (1 + i % 5), 0.1 * i, "ok" if i % 7 else "no plane found", 2e-4 * (i % 2)) for i in range(n)]


def test_rows_come_back_as_they_went_in_again_and_again():
    rows = _rows(10_000)  # nine blocks of records on disk, the last rows in memory; read back 4,096 at a time
    stored = MeasurementRows(DiskBlocks())
    stored.extend(rows[:9000])
    for r in rows[9000:]:
        stored.append(r)
    assert len(stored) == len(rows)
    for _ in range(2):
        back = list(stored)
        assert len(back) == len(rows)
        assert all(a.t_s == b.t_s and a.method == b.method and a.quantity == b.quantity and a.status == b.status
                   and a.sigma == b.sigma and a.time_ms == b.time_ms and a.sigma_systematic == b.sigma_systematic
                   and (a.value == b.value or (math.isnan(a.value) and math.isnan(b.value))) for a, b in zip(back, rows))
    assert sum(not r.ok for r in stored) == sum(not r.ok for r in rows) > 0


def test_no_rows():
    assert list(MeasurementRows()) == [] and len(MeasurementRows()) == 0
