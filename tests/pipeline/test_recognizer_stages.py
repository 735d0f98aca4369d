"""The recogniser's stages keep nothing of one scan on the :class:`ScanRecognizer` (the scan's up direction, stamps
and seeds travel in a ``ScanContext``): one recognizer used by two threads at once gives every scan exactly the
detections that sequential calls give."""

from __future__ import annotations

import json
import threading

import pytest

from semslam.pipeline import ScanRecognizer

UP = (0.0, 0.0, -1.0)  # world up seen by the simulator's downward-looking scanner (level vehicle)


@pytest.fixture(scope="module")
def db(builtin_db_fresh):
    return builtin_db_fresh


@pytest.fixture(scope="module")
def scans():
    """Four laser scans of a simulated dive, one fitting in each (elbow, tee, ball valve, socket)."""
    from semslam.simulation import SimulatorConfig, TrajectoryConfig, simulate_dataset

    mission = simulate_dataset(SimulatorConfig().replace(trajectory=TrajectoryConfig(loops=1)), seed=4,
                               scan_interval_s=5.0)
    return [(r.scan_id, mission.load_scan(r.scan_id)) for r in mission.scans]


def _outcome(result) -> str:
    """Every detection and cluster outcome of a result, exactly (floats as JSON reprs, NaN included)."""
    return json.dumps({"detections": [d.to_dict() for d in result.detections],
                       "clusters": [c.to_dict() for c in result.clusters]}, sort_keys=True)


def _recognize(rec: ScanRecognizer, scan_id: int, cloud, up) -> str:
    return _outcome(rec.recognize(cloud, seed=scan_id, stamp_s=0.5 * scan_id, scan_id=scan_id, up_scanner=up))


def test_two_threads_sharing_one_recognizer_give_the_sequential_detections(db, scans):
    """Thread A recognises every scan with the scan's up given, thread B the same scans without it (the
    configuration's: none), both at once on one fresh recognizer (its pose-model and size caches fill while both
    run): each result equals that of a sequential call. The socket's pose is kept upright only with the up, so a
    recognizer that shared the up between calls would mix the two."""
    assert len(scans) >= 3
    sequential = ScanRecognizer(db)
    expected = {(scan_id, up): _recognize(sequential, scan_id, cloud, up) for scan_id, cloud in scans
                for up in (UP, None)}
    upright = [d["extras"]["pose_upright"] for key, out in expected.items() for d in json.loads(out)["detections"]]
    assert sum(upright) >= 1 and not all(upright)  # the up changes the pose search of some class
    assert sum(len(json.loads(out)["detections"]) for out in expected.values()) >= 2 * len(scans) - 2

    shared = ScanRecognizer(db)
    got: dict = {}
    errors: list = []
    start = threading.Barrier(2)

    def work(up) -> None:
        try:
            start.wait(timeout=60)
            for scan_id, cloud in scans:
                got[(scan_id, up)] = _recognize(shared, scan_id, cloud, up)
        except Exception as exc:  # noqa: BLE001 - reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=work, args=(up,)) for up in (UP, None)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=300)
    assert not errors, errors
    assert got.keys() == expected.keys()
    for key in expected:
        assert got[key] == expected[key], key
