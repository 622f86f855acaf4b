"""Recordings on disk: the layout `boomtip simulate` writes and `boomtip process` reads.

    meta.json            format version, installation, processing settings, provenance (the scenario)
    lidar/<t_ns>.pcd     x y z intensity t label          (sensor frame)
    radar/<t_ns>.pcd     x y z range azimuth elevation range_rate label (sensor frame)
    mru.csv              t, roll, pitch, yaw, roll_rate, pitch_rate, yaw_rate
    feeder_mru.csv       the same columns, from an MRU on the feeder (when it has one)
    encoders.csv         t, slew, luff, hoist (hook scenarios)
    truth.csv            t, D, D_dot, <body>_{x,y,z,roll,pitch,yaw,vx,vy,vz,wx,wy,wz};
                         hook scenarios: t, hook_*, hook_rel_*, tip_*, joints, boom_deflection

`<t_ns>` is the acquisition time in ns from the run start, on the clock of `t` (seconds).
"""

from __future__ import annotations

import codecs
import json
from dataclasses import replace
import math
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
from pydantic import ValidationError

from boomtip.data.frames import (ENCODER_COLUMNS, HOOK_TRUTH_COLUMNS, LIFT_TRUTH_COLUMNS, MRU_COLUMNS, TRUTH_COLUMNS, Frame,
                                 FrameSource, MruLog, SourceMeta)
from boomtip.data.io.atomic import atomic_write_bytes
from boomtip.data.io.frame_files import FRAME_SENSORS, FrameFiles
from boomtip.data.io.pcd import PcdError, read_pcd, write_pcd
from boomtip.data.installation import Installation
from boomtip.data.stored_truth import StoredTruth
from boomtip.data.io.errors import RecordingError  # noqa: F401 - this module's error, where callers import it
from boomtip.data.io.output_folder import check_output_folder, output_folder  # noqa: F401 - check_output_folder: the studies'
from boomtip.data.io.samples import drop_bad_samples
from boomtip.data.keys import format_validation, leaf_keys

FORMAT_VERSION = 2
MAX_DURATION_S = 30 * 86400.0  # a month of recording; beyond is a corrupt meta.json
# Physical bounds of the logs (rad, rad/s, m): a value beyond them is a corrupt sample, refused
# with its line. Roll and pitch within +-90 deg; no vessel turns at 5 rad/s; a luffing boom
# stays within +-90 deg; no crane pays out 5 km of rope.
MRU_BOUNDS = {"roll": 1.5708, "pitch": 1.5708, "yaw": 7.0, "roll_rate": 5.0, "pitch_rate": 5.0, "yaw_rate": 5.0}
ENCODER_BOUNDS = {"slew": 1000.0, "luff": 1.5708, "hoist": 5000.0}
# No vessel turns its roll, pitch or heading by more than this per second (rad/s): a step
# faster between two samples is a glitch, and what follows it until the angle is back is too.
MRU_STEPS = {"roll": 1.0, "pitch": 1.0, "yaw": 1.0}


# ---------------------------------------------------------------------------------------
# JSON (output folders: data/io/output_folder.py)


def write_json(path: Path, obj) -> None:
    """Strict JSON: NaN and infinities are written as null (json.dumps would write NaN)."""
    text = json_text(obj, indent=2)
    atomic_write_bytes(path, (text + "\n").encode())


def json_text(obj, indent: int | None = None) -> str:
    """Strict JSON text: NaN and infinities as null, numpy values as plain numbers."""
    return json.dumps(_finite_or_null(obj), indent=indent, default=_json_default, allow_nan=False)


def _finite_or_null(o):
    if isinstance(o, dict):
        return {k: _finite_or_null(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite_or_null(v) for v in o]
    if isinstance(o, np.ndarray):
        return _finite_or_null(o.tolist())
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    return o


def _json_default(o):
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    raise TypeError(f"not JSON serialisable: {type(o)}")


def write_csv(path: Path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    table = np.column_stack([np.asarray(columns[n], dtype=float) for n in names]) if names else np.zeros((0, 0))
    from io import StringIO

    buf = StringIO()
    np.savetxt(buf, table, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    atomic_write_bytes(path, buf.getvalue().encode())


def screened_log(log: MruLog, where: str, notes: list[str] | None = None) -> MruLog:
    """An attitude log from any source (a simulation, a bag, a file already read) screened as
    read_csv screens a file's: glitches, frozen stretches, times out of order dropped and
    counted in `notes`; the same log when nothing is bad."""
    table = np.column_stack([log.t_s, log.rpy_rad, log.rpy_rate_radps])
    good = drop_bad_samples(table, list(MRU_COLUMNS), where, "sample", lambda k: f"at t = {table[k, 0]:.3f} s",
                            False, notes, "t", MRU_BOUNDS, MRU_STEPS)
    if len(good) == len(table):
        return log
    return replace(log, t_s=good[:, 0], rpy_rad=good[:, 1:4], rpy_rate_radps=good[:, 4:7])


CSV_CHUNK_ROWS = 8192  # rows parsed into an array at a time: a long log's text and Python floats are never whole in memory
UTF8_BLOCK_BYTES = 1 << 20  # the encoding's check reads this much at a time


def _check_utf8(path: Path) -> None:
    """The file decodes as UTF-8, or an error names the byte where it does not; read a block at a time."""
    decoder, offset = codecs.getincrementaldecoder("utf-8")(), 0
    try:
        with open(path, "rb") as fh:
            while block := fh.read(UTF8_BLOCK_BYTES):
                held = len(decoder.getstate()[0])  # a character's first bytes from the last block
                try:
                    decoder.decode(block)
                except UnicodeDecodeError as exc:
                    raise RecordingError(f"{path}: byte {offset - held + exc.start}: not UTF-8 text; expected a CSV of "
                                         "numbers") from None
                offset += len(block)
            decoder.decode(b"", final=True)
    except UnicodeDecodeError:  # a character cut at the end
        raise RecordingError(f"{path}: byte {offset - len(decoder.getstate()[0])}: not UTF-8 text; expected a CSV of "
                             "numbers") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None


def _text_lines(fh) -> Iterator[str]:
    """The lines of a text file read with universal newlines, split as str.splitlines splits a
    whole text (form feeds, file and group separators, NEL, U+2028 too), a line at a time."""
    for piece in fh:
        yield from piece.splitlines()


def _parsed_csv(path: Path, expected: tuple[str, ...]) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The header's names, the rows as a float64 table and each row's line number; read a line
    at a time (a 600 s truth at 200 Hz is 31 MB of text, several times that as Python floats)."""
    _check_utf8(path)  # first, wherever in the file: a binary file is that, not a bad header
    names: list[str] | None = None
    chunks, rows, line_no = [], [], []

    def flush() -> None:
        if rows:
            chunks.append(np.array(rows, dtype=float).reshape(-1, len(names)))
            rows.clear()

    try:
        with open(path, encoding="utf-8") as fh:
            for i, line in enumerate(_text_lines(fh), start=1):
                if names is None:
                    names = [c.strip() for c in line.split(",")]
                    missing = [c for c in expected if c not in names]
                    if missing:
                        raise RecordingError(f"{path}: line 1: missing column(s) {', '.join(missing)}; header is {line!r}")
                    continue
                if not line.strip():
                    continue
                parts = line.split(",")
                if len(parts) != len(names):
                    raise RecordingError(f"{path}: line {i}: {len(parts)} values, expected {len(names)}")
                try:
                    rows.append([float(v) for v in parts])
                except ValueError:
                    raise RecordingError(f"{path}: line {i}: a value is not a number: {line!r}") from None
                line_no.append(i)
                if len(rows) == CSV_CHUNK_ROWS:
                    flush()
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:  # changed since its check
        raise RecordingError(f"{path}: not UTF-8 text; expected a CSV of numbers") from None
    if names is None:
        raise RecordingError(f"{path}: empty file; expected a header {','.join(expected)}")
    flush()
    table = np.concatenate(chunks) if chunks else np.zeros((0, len(names)))
    if len(table) == 0:
        raise RecordingError(f"{path}: a header and no samples; expected rows of {','.join(expected)}")
    return names, table, np.array(line_no, dtype=np.int64)


def read_csv(path: Path, expected: tuple[str, ...], time_column: str = "t", bounds: dict[str, float] | None = None,
             steps: dict[str, float] | None = None, strict: bool = True, notes: list[str] | None = None) -> dict[str, np.ndarray]:
    """Read a numeric CSV with a header; errors name the file, line and what was expected.

    A sample (row) is bad when a value is not finite, beyond |bounds[column]|, a step from the
    log's good samples faster than steps[column] per second plus the log's noise (an angle,
    wrapped: a glitch no vessel makes), or when its time is out of the log's order
    (data/io/samples.py). `strict`: a bad sample refuses
    the file; else it is dropped, counted in `notes` with its first lines, and the stream has a gap
    there (refused when half the samples are bad: that is no log)."""
    names, table, line_no = _parsed_csv(path, expected)
    table = drop_bad_samples(table, names, str(path), "line", lambda k: str(line_no[k]), strict, notes, time_column,
                             bounds, steps)
    return {n: table[:, j] for j, n in enumerate(names)}


# ---------------------------------------------------------------------------------------
# Writing


def frame_file_name(t_s: float) -> str:
    return f"{int(round(t_s * 1e9)):013d}.pcd"


def truth_columns_of(path: Path) -> tuple[str, ...] | None:
    """The lift's truth columns when truth.csv's header is the lift's (else None: the caller's
    expectation, the hook's or the ship-to-ship one)."""
    with open(path, encoding="utf-8", errors="replace") as fh:
        header = tuple(fh.readline().strip().split(","))
    return LIFT_TRUTH_COLUMNS if header == LIFT_TRUTH_COLUMNS else None


def write_recording(
    source: FrameSource, out: Path, force: bool = False, progress: Callable[[int], None] | None = None,
    inputs: tuple[Path | None, ...] = (),
) -> dict:
    """Write every frame, the MRU log and the truth of a source into OUT (atomically; never over
    one of `inputs`)."""
    with output_folder(out, force, inputs) as staging:
        for sensor in ("lidar", "radar"):
            (staging / sensor).mkdir()
        counts = {"lidar": 0, "radar": 0}
        for frame in source:
            write_pcd(staging / frame.sensor / frame_file_name(frame.t_s), frame.points_sensor, frame.fields)
            counts[frame.sensor] += 1
            if progress:
                progress(1)
        write_csv(staging / "mru.csv", mru_columns(source.mru))
        if getattr(source, "feeder_mru", None) is not None:
            write_csv(staging / "feeder_mru.csv", mru_columns(source.feeder_mru))
        encoders = getattr(source, "encoders", None)
        if encoders is not None:
            write_csv(staging / "encoders.csv", encoders)
        if source.truth is not None:
            write_csv(staging / "truth.csv", {k: source.truth.columns[k] for k in source.truth.columns})
        meta = meta_to_json(source.meta, counts)
        write_json(staging / "meta.json", meta)
    return meta


def mru_columns(m: MruLog) -> dict[str, np.ndarray]:
    cols = {"t": m.t_s}
    for i, a in enumerate(("roll", "pitch", "yaw")):
        cols[a] = m.rpy_rad[:, i]
    for i, a in enumerate(("roll_rate", "pitch_rate", "yaw_rate")):
        cols[a] = m.rpy_rate_radps[:, i]
    return cols


def meta_to_json(meta: SourceMeta, counts: dict[str, int] | None = None) -> dict:
    from boomtip.data.frames import LIDAR_FIELDS, RADAR_FIELDS

    out = {
        "format_version": FORMAT_VERSION,
        "generator": "boomtip",
        "name": meta.name,
        "duration_s": meta.duration_s,
        # What processing is built from: the installation as documented and its own settings.
        "installation": meta.installation.model_dump(mode="json"),
        "processing": meta.processing,
        "sensors": {"lidar": {"fields": ["x", "y", "z", *LIDAR_FIELDS]}, "radar": {"fields": ["x", "y", "z", *RADAR_FIELDS]}},
        "frames": counts or {},
        "conventions": {
            "angles": "radians; R = Rz(yaw) Ry(pitch) Rx(roll) = Rotation.from_euler('xyz', [roll, pitch, yaw])",
            "mru_rates": "time derivatives of roll, pitch, yaw (rad/s)",
            "truth_twist": "velocity of the body origin and angular velocity, both in world axes",
            "radar_range_rate": "d(range)/dt in m/s, positive when the range grows",
            "lidar_t": "time offset of the point from the frame's acquisition time (s)",
            "mounts": "installation.<sensor>.mount as surveyed; the simulated world may deviate (provenance)",
        },
    }
    if meta.provenance is not None:
        # The full scenario, world included, for reproducibility only: processing never reads it.
        out["provenance"] = {"scenario": meta.provenance}
    return out


# ---------------------------------------------------------------------------------------
# Reading


class Recording(FrameSource):
    """A recording folder as a FrameSource."""

    def __init__(self, root: str | Path, strict: bool = False) -> None:
        """strict: a bad sample in a stream (mru.csv, encoders.csv, ...) refuses the recording;
        else it is dropped and counted in the notes (read_csv)."""
        self.root = Path(root)
        if not self.root.is_dir():
            raise RecordingError(f"{self.root}: no such recording folder")
        meta_path = self.root / "meta.json"
        try:
            meta = json.loads(meta_path.read_text(encoding="utf-8"))
        except UnicodeDecodeError as exc:
            raise RecordingError(f"{meta_path}: byte {exc.start}: not UTF-8 text; expected JSON") from None
        except FileNotFoundError:
            raise RecordingError(f"{meta_path}: missing; is {self.root} a boomtip recording?") from None
        except json.JSONDecodeError as exc:
            raise RecordingError(f"{meta_path}: line {exc.lineno}: not valid JSON: {exc.msg}") from None
        if not isinstance(meta, dict):
            raise RecordingError(f"{meta_path}: expected a JSON object with format_version, scenario, sensors, ...")
        version = meta.get("format_version")
        if version != FORMAT_VERSION:
            raise RecordingError(f"{meta_path}: format_version {version!r}; this boomtip reads version {FORMAT_VERSION}")
        self.meta = self._read_meta(meta, meta_path)
        streams = dict(strict=strict, notes=self.meta.notes)
        mru = read_csv(self.root / "mru.csv", MRU_COLUMNS, bounds=MRU_BOUNDS, steps=MRU_STEPS, **streams)
        if len(mru["t"]) < 2:
            raise RecordingError(f"{self.root / 'mru.csv'}: {len(mru['t'])} samples; the attitude needs at least 2")
        self.mru = MruLog.from_columns(mru)
        feeder_mru_path = self.root / "feeder_mru.csv"
        if feeder_mru_path.exists():
            feeder_mru = read_csv(feeder_mru_path, MRU_COLUMNS, bounds=MRU_BOUNDS, steps=MRU_STEPS, **streams)
            if len(feeder_mru["t"]) < 2:
                raise RecordingError(f"{feeder_mru_path}: {len(feeder_mru['t'])} samples; an attitude log needs at least 2")
            self.feeder_mru = MruLog.from_columns(feeder_mru)
        hook = (self.root / "encoders.csv").exists()
        if hook:
            self.encoders = read_csv(self.root / "encoders.csv", ENCODER_COLUMNS, bounds=ENCODER_BOUNDS, **streams)
        truth_path = self.root / "truth.csv"
        expected = (truth_columns_of(truth_path) if truth_path.exists() else None) or (HOOK_TRUTH_COLUMNS if hook else TRUTH_COLUMNS)
        if truth_path.exists():  # on disk: a long recording's truth is tens of MB
            columns = read_csv(truth_path, expected)
            self.truth = StoredTruth.of_columns(columns, tuple(columns))
        else:
            self.truth = None
        self._files = self._list_frames()

    @staticmethod
    def _read_meta(meta: dict, meta_path: Path) -> SourceMeta:
        if "installation" not in meta:
            raise RecordingError(f"{meta_path}: missing key 'installation' (the sensors, mounts and crane as "
                                 "documented; `boomtip installation --template` prints one)")
        try:
            installation = Installation.model_validate(meta["installation"])
        except ValidationError as exc:
            raise RecordingError(format_validation(exc, f"{meta_path}", "installation.",
                                                   keys=leaf_keys(Installation(), "installation"))) from None
        processing = meta.get("processing") or {}
        if not isinstance(processing, dict):
            raise RecordingError(f"{meta_path}: 'processing' must be a mapping of processing settings")
        duration = meta.get("duration_s")
        if not isinstance(duration, (int, float)) or not math.isfinite(duration) or not 0 <= duration <= MAX_DURATION_S:
            raise RecordingError(f"{meta_path}: 'duration_s' must be seconds between 0 and {MAX_DURATION_S:g}, got {duration!r}")
        prov = meta.get("provenance")
        return SourceMeta(installation=installation, duration_s=float(duration), name=str(meta.get("name", "recording")),
                          processing=processing, provenance=prov.get("scenario") if isinstance(prov, dict) else None)

    def _list_frames(self) -> FrameFiles:
        names, t_ns, sensors = [], [], []
        for code, sensor in enumerate(FRAME_SENSORS):
            folder = self.root / sensor
            if not folder.is_dir():
                continue
            for p in folder.glob("*.pcd"):
                try:
                    t = int(p.stem)
                except ValueError:
                    t = None
                if t is None or not -2**63 <= t < 2**63:  # int64
                    raise RecordingError(f"{p}: frame file names must be the acquisition time in ns, e.g. 0000100000000.pcd") from None
                t_ns.append(t)
                names.append(p.name)
                sensors.append(code)
        return FrameFiles(self.root, np.array(t_ns, dtype=np.int64), np.array(sensors, dtype=np.int8), names)

    def __len__(self) -> int:
        return len(self._files)

    def __iter__(self) -> Iterator[Frame]:
        index = {"lidar": 0, "radar": 0}
        for t_ns, sensor, path in self._files:
            i = index[sensor]
            index[sensor] += 1
            t_s = t_ns * 1e-9
            try:
                points, fields = read_pcd(path)
            except PcdError as exc:
                yield Frame(sensor, i, t_s, np.zeros((0, 3)), {}, path=str(path), error=str(exc))
                continue
            bad = self._implausible(sensor, points)
            if bad:
                yield Frame(sensor, i, t_s, np.zeros((0, 3)), {}, path=str(path), error=f"{path}: {bad}")
                continue
            yield Frame(sensor, i, t_s, points, fields, path=str(path))

    def _implausible(self, sensor: str, points: np.ndarray) -> str | None:
        """A frame whose points are mostly non-finite or beyond the sensor's range is corrupt
        data behind a valid header (a few NaN or dropped points are normal and kept)."""
        if len(points) == 0:
            return None
        cfg = getattr(self.meta.installation, sensor)
        with np.errstate(invalid="ignore", over="ignore"):
            r = np.sqrt(np.einsum("ij,ij->i", points, points))
        ok = np.count_nonzero(np.isfinite(r) & (r <= cfg.max_range_m * 1.05))
        if ok < 0.5 * len(points):
            return (f"{len(points) - ok} of {len(points)} points are non-finite or beyond the {cfg.max_range_m:g} m "
                    "range: corrupt point data")
        return None
