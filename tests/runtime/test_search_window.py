"""The search window (issue 43): a frame runs only the modules around the last accepted place, the first frame
and a lost robot run the whole route, and a window over the whole route is the global localiser."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import onnx as onnx_lib
import pytest
from scipy import sparse

from vprsnn_export.cli import main
from vprsnn_export.config import preset
from vprsnn_export.data.dataset import load_dataset
from vprsnn_export.data.synthetic import synthetic_route
from vprsnn_export.errors import InvalidValueError
from vprsnn_export.io.checkpoint import save_checkpoint
from vprsnn_export.network.modules import module_regions
from vprsnn_export.readout.sequence import SequenceOptions
from vprsnn_export.runtime.deployment import deploy
from vprsnn_export.runtime.localize import Localizer, SearchWindow, network_part, operating_point
from vprsnn_export.runtime.tracking import tracking_rows
from vprsnn_export.targets.contract import search_rule
from vprsnn_export.targets.intsim import IntegerNetwork
from vprsnn_export.targets.loihi_description import describe
from vprsnn_export.targets.onnx_session import run_session, session
from vprsnn_export.targets.onnx_target import write_onnx
from vprsnn_export.trainer.pipeline import train_and_calibrate

PLACES = 300
K3 = SequenceOptions(ks=(3,))


@pytest.fixture(scope="module")
def route():
    """The lean preset (100-place modules) on a 300-place synthetic route, and its winter traversal as a query."""
    cfg = preset("lean").replace(**{"train.epochs": 6})
    data = load_dataset(f"synthetic:{PLACES}", ["summer", "winter"], cfg.preprocess)
    ckpt = train_and_calibrate(data, ["summer"], cfg, progress=False)
    query = data.query("winter", ["summer"])
    point, _, _ = operating_point(Localizer(ckpt, options=K3), query.images, query.place_ids, precision=0.9)
    assert point.threshold is not None
    return ckpt, data, query, point.threshold


def answers(decisions):
    return [(d.place_id, d.confidence, d.accepted, d.velocity) for d in decisions]


def test_the_windows_modules_are_those_its_places_meet():
    regions = module_regions(1000, 100)
    window = SearchWindow(300)
    assert window.modules(500.0, regions) == (3, 7)  # places 350..649 meet modules 3..6
    assert window.modules(0.0, regions) == (0, 3)  # clipped at the route's start: places 0..299
    assert window.modules(999.4, regions) == (7, 10)  # and at its end: places 700..999
    assert SearchWindow(5000).modules(10.0, regions) == (0, 10)


def test_the_window_follows_accepted_places_and_widens_after_its_patience():
    window = SearchWindow(300, patience=3)
    assert window.follow(None, 0, 120, True, 1.0) == (120.0, 0, 0)  # a global frame accepted: the window goes there
    assert window.follow(None, 0, 120, False, 1.0) == (120.0, 2, 0)  # not accepted: one more miss looks again
    assert window.follow(None, 0, None, False, 1.0) == (None, 2, 0)  # no place: global again
    assert window.follow(50.0, 1, 57, True, 1.5) == (57.0, 0, 0)
    assert window.follow(50.0, 1, 57, False, 1.5) == (51.5, 2, 1)  # unaccepted: on at the velocity
    assert window.follow(50.0, 2, 57, False, 1.5) == (None, 3, 1)  # the third miss in a row: the next frame is global


def test_a_window_following_within_near_places_moves_to_an_unaccepted_decision_near_the_expected_place():
    window = SearchWindow(300, patience=3, near=3)
    assert window.follow(50.0, 1, 54, False, 1.5) == (54.0, 1, 1)  # 2.5 from 51.5: on track, no miss
    assert window.follow(50.0, 2, 57, False, 1.5) == (None, 3, 1)  # 5.5 from 51.5: a miss, the third: global next
    assert window.follow(50.0, 1, 57, True, 1.5) == (57.0, 0, 0)  # accepted: as without near
    assert window.follow(None, 0, 120, False, 1.0) == (120.0, 2, 0)  # a global frame: as without near
    with pytest.raises(InvalidValueError, match="near must be"):
        SearchWindow(300, near=0)


def test_a_window_lost_for_lost_after_frames_runs_the_whole_route_until_a_decision_is_accepted():
    window = SearchWindow(300, patience=3, near=3, lost_after=4)
    assert window.follow(50.0, 0, 52, False, 1.5, 2) == (52.0, 0, 3)  # followed: no miss, but one more unaccepted
    assert window.follow(50.0, 0, 52, False, 1.5, 3) == (None, 0, 4)  # the fourth in a row: lost, global next
    assert window.lost(4) and not window.lost(3) and not SearchWindow(300).lost(100)
    assert window.follow(None, 0, 900, False, 1.0, 4) == (None, 0, 4)  # lost: global again while unaccepted
    assert window.follow(None, 0, 900, True, 1.0, 4) == (900.0, 0, 0)  # found: the window goes there
    assert window.follow(None, 0, 900, False, 1.0, 0) == (900.0, 2, 0)  # a global frame not lost: as before
    with pytest.raises(InvalidValueError, match="lost after must be"):
        SearchWindow(300, lost_after=0)


def test_a_lost_robot_forgets_the_lost_windows_frames(route):
    """After ``lost_after`` unaccepted window frames the readout's recent frames are dropped: the next (global)
    frame decides as a fresh stream's first frame would."""
    ckpt, _, query, threshold = route
    search = SearchWindow(100, near=300, lost_after=2)  # every unaccepted window frame followed: lost after two
    decisions = Localizer(ckpt, options=K3, threshold=1.0, search=search).run_inputs(query.images[:12])
    kinds = [d.search for d in decisions]
    assert kinds[:4] == ["global", "window", "window", "global"] and set(kinds[3:]) == {"global"}
    fresh = Localizer(ckpt, options=K3, threshold=1.0)
    index, confidence, _ = fresh.stream.push(fresh.counts(query.images[3:4], 3)[0], None)  # frame 3 alone
    assert (decisions[3].place_id, decisions[3].confidence) == (int(ckpt.reference_place_ids[index]), confidence)
    assert decisions[4].confidence != confidence  # and the stream goes on from there


def test_a_window_over_the_whole_route_decides_as_the_global_localiser(route):
    ckpt, _, query, threshold = route
    whole = Localizer(ckpt, options=K3, threshold=threshold).run_inputs(query.images[:60])
    window = Localizer(ckpt, options=K3, threshold=threshold, search=SearchWindow(PLACES)).run_inputs(query.images[:60])
    assert answers(window) == answers(whole)
    assert window[0].search == "global" and {d.search for d in window[1:]} <= {"window", "global"}


def test_a_frame_runs_the_windows_modules_alone_and_the_first_frame_the_route(route):
    ckpt, _, query, threshold = route
    decisions = Localizer(ckpt, options=K3, threshold=threshold, search=SearchWindow(100)).run_inputs(query.images)
    neurons = ckpt.calibration.shape[0]
    assert decisions[0].search == "global"
    windowed = [d for d in decisions if d.search == "window"]
    assert len(windowed) > len(decisions) // 2  # it tracks most of the route
    assert all(d.events is not None and d.events > 0 for d in decisions)
    # every input spike reaches the neurons that run: a 100-place window meets at most 2 of the 3 modules
    assert max(d.events for d in windowed) < max(d.events for d in decisions if d.search == "global")
    assert neurons == 3 * ckpt.config.network.n_neurons


def test_a_kidnapped_robot_is_relocalised(route):
    ckpt, _, query, threshold = route
    jump = np.r_[np.arange(0, 60), np.arange(220, PLACES)]  # 160 places ahead after frame 59
    truth = query.place_ids[jump]

    def right(localizer):
        decisions = localizer.run_inputs(query.images[jump])
        return decisions, [
            d.place_id is not None and abs(d.place_id - t) <= 1 for d, t in zip(decisions, truth, strict=True)
        ]

    _, whole = right(Localizer(ckpt, options=K3, threshold=threshold))
    decisions, tracked = right(Localizer(ckpt, options=K3, threshold=threshold, search=SearchWindow(100)))
    assert sum(tracked) >= sum(whole) - 3  # tracking loses nothing against the whole route, before and after
    back = next(j for j in range(60, len(jump)) if tracked[j]) - 60
    assert back <= next(j for j in range(60, len(jump)) if whole[j]) - 60 + 3  # the patience's frames at most
    assert any(d.search == "global" for d in decisions[60 : 60 + back + 1])  # found by a global re-localisation


def test_the_tracking_protocol_beside_the_global_one(route):
    ckpt, _, query, _ = route
    rows = tracking_rows(
        ckpt, query.images, query.place_ids, query.truth, SequenceOptions(ks=(1, 3)), SearchWindow(100), precision=0.9
    )
    assert [(r.protocol, r.k) for r in rows] == [("global", 1), ("window 100", 1), ("global", 3), ("window 100", 3)]
    for whole, window in (rows[:2], rows[2:]):
        assert window.events_per_frame < whole.events_per_frame and whole.relocalisations == 0
        assert whole.window_events_per_frame == whole.events_per_frame  # the global protocol has no window frames
        assert whole.window_ms_per_frame == whole.ms_per_frame and window.window_ms_per_frame > 0
        assert 0 < window.window_events_per_frame < whole.events_per_frame
        assert 0 <= window.accuracy <= 1 and 0 <= window.r_at_100p <= 1


def test_the_integer_simulator_tracks_the_same_pushed_or_batched(route):
    ckpt, data, query, _ = route
    model = deploy(ckpt, "0" * 64, 8, reference_images={"summer": data.traversal("summer")})
    frames = [*synthetic_route(PLACES, ("winter",))["winter"][:40]]
    frames[7] = np.full_like(frames[7], 128)  # a frame without contrast: no decision, it still moves the stream on
    search = SearchWindow(100)
    pushed = Localizer(model, options=K3, threshold=0.5, search=search)
    one = [pushed.push(f) for f in frames]
    batched = Localizer(model, options=K3, threshold=0.5, search=search).run_batch(frames)
    assert answers(one) == answers(batched) and [d.events for d in one] == [d.events for d in batched]
    assert one[7].reason == "no contrast" and one[7].place_id is None
    assert {d.search for d in one} == {"global", "window"}


def test_the_onnx_graph_tracks_as_the_integer_simulator_frame_for_frame(route, tmp_path):
    """The exported graph runs the window's modules through its ``modules`` input: the same counts as the integer
    simulator's part network, so the same decision, events and modules on every frame, a kidnap included."""
    ckpt, data, query, _ = route
    model = deploy(ckpt, "0" * 64, 8, reference_images={"summer": data.traversal("summer")})
    graph = write_onnx(model, tmp_path / "net.onnx", with_raster=True)
    jump = np.r_[np.arange(0, 40), np.arange(200, 240)]  # 160 places ahead after frame 39
    search = SearchWindow(100)
    integer = Localizer(model, options=K3, threshold=0.5, search=search).run_inputs(query.images[jump])
    onnx = Localizer(model, options=K3, threshold=0.5, search=search, backend="onnx", onnx_path=graph)
    tracked = onnx.run_inputs(query.images[jump])
    assert answers(tracked) == answers(integer)
    assert [(d.events, d.search, d.modules) for d in tracked] == [(d.events, d.search, d.modules) for d in integer]
    assert {d.search for d in tracked} == {"global", "window"} and {d.modules for d in tracked} > {(0, 3)}
    spikes = onnx.spikes(query.images[:5], 0)
    run = run_session(session(graph), spikes, modules=(1, 3))
    part = IntegerNetwork(network_part(model, slice(model.config.network.n_neurons, None))).run(spikes, record=True)
    assert np.array_equal(run.counts, part.counts.numpy()) and np.array_equal(run.raster, part.raster.numpy())
    rule = search_rule(100, PLACES)  # the rule is in the files: ONNX metadata and network.json
    old = onnx_lib.load(str(graph))
    assert json.loads({p.key: p.value for p in old.metadata_props}["vprsnn.search"]) == rule
    assert describe(model).header["search"] == rule and "idle for the frame" in rule["run"]
    # a graph written before the modules input: its default a constant
    old.graph.input.pop()
    onnx_lib.save(old, str(tmp_path / "old.onnx"))
    assert np.array_equal(
        run_session(session(tmp_path / "old.onnx"), spikes).counts, run_session(session(graph), spikes).counts
    )
    with pytest.raises(InvalidValueError, match="needs a graph with the modules input"):
        Localizer(model, threshold=0.5, search=search, backend="onnx", onnx_path=tmp_path / "old.onnx")


def test_search_window_refusals(route, tmp_path, capsys):
    ckpt, _, _, threshold = route
    with pytest.raises(InvalidValueError, match="operating point"):
        Localizer(ckpt, search=SearchWindow(100))
    with pytest.raises(InvalidValueError, match="search window must be a whole number"):
        SearchWindow(0)
    with pytest.raises(InvalidValueError, match="patience"):
        SearchWindow(100, patience=0)
    single = train_and_calibrate(
        load_dataset("synthetic:12", ["summer"], ckpt.config.preprocess),
        ["summer"],
        ckpt.config.replace(**{"train.module_size": 0, "train.epochs": 1, "network.n_neurons": 12}),
        progress=False,
    )
    with pytest.raises(InvalidValueError, match="ensemble of modules"):
        Localizer(single, threshold=threshold, search=SearchWindow(4))
    path = save_checkpoint(tmp_path / "net.npz", ckpt)
    assert main(["localize", str(path), "--frames", str(tmp_path), "--patience", "2"]) == 2
    assert capsys.readouterr().err.strip().count("\n") == 0
    assert main(["localize", str(path), "--calibrate", "winter", "--search-window", "100"]) == 2
    assert "--search-window" in capsys.readouterr().err


def test_a_decision_line_has_events_and_search_only_with_a_window(route):
    ckpt, _, query, threshold = route
    plain = Localizer(ckpt, options=K3, threshold=threshold).run_inputs(query.images[:2])[1].to_dict()
    window = Localizer(ckpt, options=K3, threshold=threshold, search=SearchWindow(100)).run_inputs(query.images[:2])
    assert "events" not in plain and "search" not in plain
    line = json.loads(json.dumps(window[1].to_dict()))
    assert set(line) - set(plain) == {"events", "search", "modules"}
    assert window[0].modules == (0, 3) and line["modules"] == list(window[1].modules)  # the first frame: every module


def test_evaluate_scores_the_tracking_protocol_beside_the_global_one(route, tmp_path, capsys):
    ckpt, _, _, _ = route
    path = save_checkpoint(tmp_path / "net.npz", ckpt)
    capsys.readouterr()
    argv = ["evaluate", str(path), "--query", "winter", "--k", "3", "--search-window", "100", "--quiet"]
    assert main([*argv, "--json"]) == 0
    tracking = json.loads(capsys.readouterr().out)["tracking"]
    assert [(row["protocol"], row["k"]) for row in tracking] == [("global", 3), ("window 100", 3)]
    assert tracking[1]["events_per_frame"] < tracking[0]["events_per_frame"]
    assert main(argv) == 0
    assert "tracking within 100 places (patience 3)" in capsys.readouterr().out
    assert main(["evaluate", str(path), "--query", "winter", "--patience", "2"]) == 2
    assert "--patience, --follow-within and --lost-after are for --search-window" in capsys.readouterr().err
    assert main([*argv, "--follow-within", "3"]) == 0
    assert "tracking within 100 places (patience 3, following within 3)" in capsys.readouterr().out
    assert main(["evaluate", str(path), "--query", "winter", "--follow-within", "3"]) == 2
    assert "--patience, --follow-within and --lost-after are for --search-window" in capsys.readouterr().err
    assert main([*argv, "--follow-within", "3", "--lost-after", "4"]) == 0
    assert "(patience 3, following within 3, lost after 4)" in capsys.readouterr().out
    assert main(["evaluate", str(path), "--query", "winter", "--lost-after", "4"]) == 2


def test_a_sparse_calibration_localises_as_the_dense_one(route):
    """A long route's checkpoint holds S^R as CSR (trainer.calibrate): the localiser, global and windowed, and its
    operating point decide every frame as they do with the dense S^R."""
    ckpt, _, query, threshold = route
    csr = replace(ckpt, calibration=sparse.csr_array(ckpt.calibration))
    for search in (None, SearchWindow(100)):
        dense = Localizer(ckpt, options=K3, threshold=threshold, search=search).run_inputs(query.images[:80])
        sparse_ = Localizer(csr, options=K3, threshold=threshold, search=search).run_inputs(query.images[:80])
        assert answers(sparse_) == answers(dense)
    point = operating_point(Localizer(csr, options=K3), query.images, query.place_ids, precision=0.9)[0]
    assert point.threshold == threshold
