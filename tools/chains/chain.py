"""What every chain is: built from a frame source's installation and the processing settings
(never from the simulated world), it takes the source's frames one at a time and, at the end,
makes its estimates and writes them. The runner (tools/chains/runner.py) knows chains only
through this protocol:

    for frame in chain.frames(source): viz.log_frame(chain.process(frame))
    result = chain.finish(); chain.outputs(out, result); chain.kpis(result, truth, windows)
    chain.report(out, kpis, result, truth, pictures); chain.visualise_result(viz, result, truth)

A chain may also split `process` into `perceive(frame)` (per-frame perception that may run
ahead in another process; `without_clouds(perceived)` what crosses back when no cloud is
wanted) and `fuse(perceived)` (in order, here); score how bad a frame's detection is with
`frame_score(output, truth)`, and its report then draws the pictured frames' detections
(`pictures`, tools/chains/pictures.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Iterator, Protocol, runtime_checkable

from boomtip.data.frames import Frame, FrameSource, Truth
from boomtip.perception.timing import StageTimes

__all__ = ["Chain", "ChainError", "FrameOutput", "NullVisualiser", "Visualiser"]


class ChainError(ValueError):
    """A chain cannot be built from what the source provides: the message names the key."""


@runtime_checkable
class FrameOutput(Protocol):
    """What a chain made of one frame (its stage times, and what its visualiser draws)."""

    times: StageTimes | None


class Visualiser(Protocol):
    """Where a run's frames and estimates are drawn (the rerun recording)."""

    def log_frame(self, output: FrameOutput | None) -> None: ...

    def close(self) -> None: ...


class NullVisualiser:
    """The visualiser when none is wanted: every logging call does nothing."""

    def __getattr__(self, name: str) -> Callable[..., None]:
        return lambda *args, **kwargs: None


@runtime_checkable
class Chain(Protocol):
    """A pipeline (perception) and an estimator (fusion) wired together per frame."""

    name: str  # what kpis.json calls the run's chain

    def frames(self, source: FrameSource) -> Iterator[Frame]:
        """The source's frames in time order (a chain may have them made ahead of it)."""
        ...

    def process(self, frame: Frame) -> FrameOutput | None:
        """One frame through the pipeline and into the estimator."""
        ...

    def finish(self) -> Any:
        """The run's estimates, once every frame is in."""
        ...

    def outputs(self, out: Path, result: Any) -> list[str]:
        """The estimates' files in `out`; their names."""
        ...

    def kpis(self, result: Any, truth: Truth | None, windows: list[tuple[float, float]] = ()) -> dict:
        """kpis.json's blocks: what was estimated and, with truth, how well."""
        ...

    def report(self, out: Path, kpis: dict, result: Any, truth: Truth | None, pictures: Any = None) -> list[str]:
        """report.md and plots in `out` (with the detections of the frames `pictures` chose, when
        the chain draws them); their names."""
        ...

    def visualiser(self, path: Path, source: FrameSource) -> Visualiser:
        """The rerun recording of the run at `path`."""
        ...

    def visualise_result(self, viz: Visualiser, result: Any, truth: Truth | None) -> None:
        """The estimates (and the truth) drawn at the end."""
        ...
