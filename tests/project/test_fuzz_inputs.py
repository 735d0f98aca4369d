"""Derandomised fuzzing of every text input of a dive (issue 18, item 2): dataset directories (mission.json and
the CSV logs), vehicle and topic-map TOML, SLAM config files and detections files. Each case is a seeded
mutation (bytes flipped, the file cut, lines duplicated or swapped, a number made huge or NaN, a value retyped);
only a :class:`~semslam.errors.SemslamError` may escape, each case ends within seconds and its peak allocation
stays under 256 MiB."""

from __future__ import annotations

import shutil
import time
import tracemalloc
import zlib

import numpy as np
import pytest

from semslam.dataset import read_dataset, read_vehicle_toml, write_dataset
from semslam.dataset.rosbag import read_topic_map
from semslam.errors import SemslamError

N_CASES = 60


def _mutate(data: bytes, rng: np.random.Generator) -> bytes:
    """One seeded mutation of a text file."""
    kind = int(rng.integers(7))
    lines = data.split(b"\n")
    if kind == 0 and data:  # flip bytes
        b = bytearray(data)
        for i in rng.integers(0, len(b), size=int(rng.integers(1, 8))):
            b[i] = int(rng.integers(0, 256))
        return bytes(b)
    if kind == 1:  # cut
        return data[: int(rng.integers(0, max(len(data), 1)))]
    if kind == 2 and len(lines) > 2:  # duplicate or swap lines
        i, j = (int(v) for v in rng.integers(1, len(lines), size=2))
        lines[i], lines[j] = lines[j], lines[i]
        lines.insert(i, lines[j])
        return b"\n".join(lines)
    if kind == 3:  # a number made absurd
        words = data.replace(b",", b" , ").replace(b"=", b" = ").split(b" ")
        idx = [k for k, w in enumerate(words) if w.strip().replace(b".", b"").replace(b"-", b"").isdigit()]
        if idx:
            words[int(rng.choice(idx))] = [b"1e308", b"nan", b"-1e9", b"inf", b"0", b'"x"', b"true"][int(rng.integers(7))]
            return b" ".join(words).replace(b" , ", b",").replace(b" = ", b"=")
    if kind == 4:  # binary garbage appended
        return data + bytes(rng.integers(0, 256, size=64, dtype=np.uint8))
    if kind == 5 and len(lines) > 1:  # a line dropped
        del lines[int(rng.integers(len(lines)))]
        return b"\n".join(lines)
    return data.replace(b"[", b"{", 1)  # a type changed


#: peak Python + numpy allocation of one case (tracemalloc sees numpy's buffers); the inputs are a few kB
MAX_CASE_BYTES = 256 * 2**20


def _only_semslam_errors(call, path, original: bytes, seed: int) -> int:
    """Each mutated case: only a SemslamError escapes, it ends within 10 s and allocates at most
    MAX_CASE_BYTES at its peak (a declared size or stamp gap that makes the reader allocate gigabytes fails)."""
    rng = np.random.default_rng(seed)
    failures = 0
    tracemalloc.start()
    try:
        for _ in range(N_CASES):
            path.write_bytes(_mutate(original, rng))
            tracemalloc.reset_peak()
            t0 = time.perf_counter()
            try:
                call()
            except SemslamError:
                failures += 1
            assert time.perf_counter() - t0 < 10.0
            peak = tracemalloc.get_traced_memory()[1]
            assert peak < MAX_CASE_BYTES, f"a case of {path.name} allocated {peak / 2**20:.0f} MiB"
    finally:
        tracemalloc.stop()
    path.write_bytes(original)
    return failures


@pytest.fixture(scope="module")
def mission_dir(tmp_path_factory):
    from semslam.simulation.synthetic import square_dataset

    return write_dataset(square_dataset(seed=1, loops=1), tmp_path_factory.mktemp("fz") / "m")


@pytest.mark.parametrize("name", ["mission.json", "vehicle.toml", "dvl.csv", "ahrs.csv", "depth.csv",
                                  "ground_truth/vehicle.csv", "ground_truth/objects.csv"])
def test_mission_directory_files(mission_dir, tmp_path, name):
    d = tmp_path / "m"
    shutil.copytree(mission_dir, d)
    original = (d / name).read_bytes()
    n = _only_semslam_errors(lambda: read_dataset(d), d / name, original, seed=zlib.crc32(name.encode()))
    assert n > 0  # the mutations do reach the checks


def test_vehicle_and_topic_map_files(mission_dir, tmp_path):
    v = tmp_path / "vehicle.toml"
    v.write_bytes((mission_dir / "vehicle.toml").read_bytes())
    assert _only_semslam_errors(lambda: read_vehicle_toml(v), v, v.read_bytes(), seed=3) > 0
    t = tmp_path / "topics.toml"
    t.write_text('[topics]\nscans = "/p"\nattitude = "/imu"\ndvl = "/dvl"\ndepth = "/pressure"\n\n'
                 '[frames]\nattitude = "enu"\ndvl = "flu"\ndepth = "enu"\nvehicle_frame_id = "base_link"\n')
    assert _only_semslam_errors(lambda: read_topic_map(t), t, t.read_bytes(), seed=4) > 0


def test_slam_config_and_detections_files(tmp_path):
    import json

    from semslam.run.config import load_run_config
    from semslam.simulation.synthetic import square_dataset
    from semslam.simulation.detections import TruthDetectionConfig, simulate_detections
    from semslam.slam import SlamConfig
    from semslam.io.detections import read_detections_jsonl, write_detections_jsonl

    c = tmp_path / "config.json"
    c.write_text(json.dumps(SlamConfig().to_dict(), indent=1))

    def load_config():  # the one front door every command reads --config through
        load_run_config(c).slam_config()

    assert _only_semslam_errors(load_config, c, c.read_bytes(), seed=5) > 0
    dets = simulate_detections(square_dataset(seed=1, loops=1), TruthDetectionConfig(), seed=1)
    f = tmp_path / "d.jsonl"
    write_detections_jsonl(f, {k: v[:1] for k, v in list(dets.items())[:6]})
    assert _only_semslam_errors(lambda: read_detections_jsonl(f), f, f.read_bytes(), seed=6) > 0
