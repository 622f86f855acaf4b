"""What every chain is (tools/chains/chain.py) and what the runner reads of a source's
provenance (tools/chains/provenance.py): each chain satisfies the protocol the runner calls it
through, with the signatures it calls; the null visualiser swallows every call; a chain that
cannot be built says so as a ValueError; the labels and outage windows come from the
provenance alone; and build_chain picks the chain runner.py documents. Sources are small
stubs with a hand-made MRU log and no frames: nothing here simulates, and the one run (the
runner on no frame at all) is marked slow."""

from __future__ import annotations

import inspect
from pathlib import Path

import numpy as np
import pytest

from boomtip.data.frames import FrameSource, MruLog, SourceMeta
from boomtip.data.installation import Installation
from boomtip.tools.chains import runner
from boomtip.tools.chains.chain import Chain, ChainError, FrameOutput, NullVisualiser
from boomtip.tools.chains.heave import HeaveChain
from boomtip.tools.chains.hook import HookChain
from boomtip.tools.chains.provenance import outage_windows, run_labels
from boomtip.tools.chains.ship import ShipChain
from boomtip.tools.config.processing import Processing

NO_LIDAR = {"lidar": {"enabled": False}}


class Source(FrameSource):
    """A source with no frames: its metadata, a 10 s MRU log at 200 Hz and, when asked, encoders."""

    def __init__(self, installation: dict | None = None, provenance: dict | None = None, encoders: bool = False,
                 name: str = "stub", duration_s: float = 10.0) -> None:
        self.meta = SourceMeta(Installation.model_validate(installation or {}), duration_s, name, provenance=provenance)
        t = np.arange(2001) / 200.0
        self.mru = MruLog(t, np.column_stack([0.01 * np.sin(t), 0.01 * np.cos(t), np.zeros_like(t)]),
                          np.column_stack([0.01 * np.cos(t), -0.01 * np.sin(t), np.zeros_like(t)]))
        self.truth = None
        te = np.arange(1001) / 100.0
        self.encoders = ({"t": te, "slew": np.zeros_like(te), "luff": np.full_like(te, 0.8), "hoist": np.full_like(te, 60.0)}
                         if encoders else None)

    def __iter__(self):
        return iter(())

    def __len__(self) -> int:
        return 0


# -- the protocol --------------------------------------------------------------------------------

CHAINS = {
    "heave": lambda: HeaveChain(Source(), Processing()),
    "ship": lambda: ShipChain(Source(), Processing()),
    "hook": lambda: HookChain(Source(encoders=True), Processing()),
}
PROTOCOL_METHODS = ("frames", "process", "finish", "outputs", "kpis", "report", "visualiser", "visualise_result")


def _parameters(fn) -> list[tuple[str, object]]:
    """A method's parameters after self: name and default."""
    return [(p.name, p.default) for p in list(inspect.signature(fn).parameters.values())[1:]]


@pytest.mark.parametrize("kind", sorted(CHAINS))
def test_every_chain_satisfies_the_protocol_with_its_signatures(kind):
    chain = CHAINS[kind]()
    assert isinstance(chain, Chain)
    assert chain.name == ("hook" if kind == "hook" else "heave")  # kpis.json's chain; the ship chain's is the heave chain's
    for name in PROTOCOL_METHODS:
        assert _parameters(getattr(type(chain), name)) == _parameters(getattr(Chain, name)), name
    # as the runner calls them: finish() with nothing, process(frame) with one frame
    assert _parameters(type(chain).finish) == [] and [n for n, _ in _parameters(type(chain).process)] == ["frame"]


def test_something_without_the_protocols_methods_is_no_chain():
    class Half:
        name = "half"

        def process(self, frame):
            return None

    assert not isinstance(Half(), Chain) and not isinstance(object(), Chain)


def test_a_frame_output_is_anything_with_stage_times():
    class Out:
        times = None

    assert isinstance(Out(), FrameOutput) and not isinstance(object(), FrameOutput)


def test_the_null_visualiser_swallows_any_call():
    viz = NullVisualiser()
    assert viz.log_frame(object()) is None and viz.close() is None
    assert viz.log_hook_tracks(np.zeros(3), np.zeros((3, 3)), None, "ekf_flexible") is None
    assert viz.anything_at_all(1, 2, three=3) is None and viz.log_estimates() is None


# -- when a chain cannot be built --------------------------------------------------------------------

def test_a_chain_error_is_a_value_error():
    assert issubclass(ChainError, ValueError)


@pytest.mark.parametrize("build, installation, encoders, names", [
    (HeaveChain, {"lidar": {"enabled": False}, "radar": {"enabled": False}}, False, "installation.lidar.enabled"),
    (HookChain, {}, False, "the hook chain needs the crane's encoder stream"),
    (HookChain, NO_LIDAR, True, "installation.lidar.enabled is false"),
])
def test_a_chain_that_cannot_be_built_says_which_key(build, installation, encoders, names):
    with pytest.raises(ValueError, match=names) as err:
        build(Source(installation, encoders=encoders), Processing())
    assert type(err.value) is ChainError


# -- the provenance ----------------------------------------------------------------------------------

WORLD = {"lidar": {"outages_s": [[9.0, 14.0]]}, "radar": {"outages_s": [[3.0, 4.0], [20.0, 21.0]]},
         "mru": {"outages_s": [[11.0, 13.0]]}, "hook": {"program": "lift-and-lower"}}


def test_run_labels_read_the_provenance():
    src = Source(provenance={"seed": 7, "world": WORLD}, name="sts-loaded", duration_s=12.5)
    assert run_labels(src, "heave") == {"scenario": "sts-loaded", "seed": 7, "duration_s": 12.5, "chain": "heave"}
    assert run_labels(src, "hook") == {"scenario": "sts-loaded", "seed": 7, "duration_s": 12.5, "chain": "hook",
                                       "program": "lift-and-lower"}


@pytest.mark.parametrize("provenance", [None, {}, {"world": None}, {"world": {"hook": None}}, {"world": {"hook": {}}}])
def test_a_recording_without_a_world_is_labelled_with_what_it_has(provenance):
    src = Source(provenance=provenance, name="rec", duration_s=3.0)
    assert run_labels(src, "hook") == {"scenario": "rec", "seed": None, "duration_s": 3.0, "chain": "hook"}
    assert outage_windows(src) == []


def test_outage_windows_are_the_sensors_sorted():
    src = Source(provenance={"world": WORLD})
    assert outage_windows(src) == [(3.0, 4.0), (9.0, 14.0), (11.0, 13.0), (20.0, 21.0)]
    assert outage_windows(src, ("mru",)) == [(11.0, 13.0)]
    assert outage_windows(src, ("lidar", "radar")) == [(3.0, 4.0), (9.0, 14.0), (20.0, 21.0)]
    assert outage_windows(Source(provenance={"world": {"lidar": None, "radar": {}}})) == []


# -- which chain -------------------------------------------------------------------------------------

@pytest.mark.parametrize("chain, installation, encoders, feeder, expected", [
    (None, {}, True, True, HookChain),  # an encoder stream: the hook chain
    ("hook", {}, True, True, HookChain),
    (None, {}, False, True, ShipChain),  # none, a LiDAR and the feeder on: the feeder beside the heave chain
    ("heave", {}, True, True, ShipChain),  # asked for, encoders or not
    (None, {}, False, False, HeaveChain),  # the feeder switched off
    (None, NO_LIDAR, False, True, HeaveChain),  # no LiDAR: no feeder
    ("heave", NO_LIDAR, True, True, HeaveChain),
])
def test_build_chain_picks_the_documented_chain(chain, installation, encoders, feeder, expected):
    processing = Processing.model_validate({"chain": chain, "feeder": {"enabled": feeder}})
    built = runner.build_chain(Source(installation, encoders=encoders), processing)
    assert type(built) is expected


def test_build_chain_asked_for_the_hook_without_encoders_refuses():
    with pytest.raises(ChainError, match="encoder stream"):
        runner.build_chain(Source(), Processing(chain="hook"))


def test_processing_for_prefers_the_given_then_the_sources():
    src = Source()
    given = Processing(seed=5)
    assert runner.processing_for(src, given) is given
    src.meta.processing = {"seed": 9}
    assert runner.processing_for(src).seed == 9
    src.meta.processing = {}
    assert runner.processing_for(src) == Processing()


@pytest.mark.slow  # the runner's whole wiring, if on no frame
def test_a_run_of_no_frames_is_labelled_and_warned(tmp_path: Path):
    """The runner's wiring end to end on a source with no frame at all (nothing to process)."""
    src = Source(provenance={"seed": 3, "world": WORLD}, name="empty", duration_s=2.0)
    res = runner.run_into(src, tmp_path, Processing(feeder={"enabled": False}), report=False)
    assert res.chain == "heave" and res.kpis["scenario"] == "empty" and res.kpis["seed"] == 3
    assert "empty: no frame to process (an empty recording?): no measurement, no estimate" in res.kpis["warnings"]
    assert {"measurements.csv", "estimates.csv", "kpis.json"} <= set(res.written)
