"""Fuzz harness for the inputs of a dive (issue 31, item 8): ROS bags (truncation, bit flips, zeroed blocks, lying
headers, stamp games), TOML files (topic maps, vehicle files, run configurations) and model folders (models.toml and
meshes). Seeded and bounded (cases per family, a time budget): the same seed gives the same cases.

Each case goes through the public entry point: a bag through ``semslam run BAG --db builtin --mode dr --no-report
--json`` (``semslam.cli.main.main`` in a subprocess with a timeout and an address-space limit), a TOML file or a
model folder through its library reader (``read_topic_map``, ``read_vehicle_toml``, ``load_run_config``,
``read_models``) in the same kind of subprocess. Each case is classified:

- ``clean error``: a one-line error (a :class:`~semslam.errors.SemslamError`; the CLI's one line, exit 1 or 2);
- ``ran`` / ``ran, damage counted``: the run ended (exit 0, or 3 for a bad verdict); "damage counted" when its
  health verdict reports a damaged recording or stamps out of order (:mod:`semslam.run.damage`);
- ``TRACEBACK``: anything else escaped; ``HANG``: the timeout; ``>2 GB``: the address-space limit was hit;
- ``LOST FILE``: an input file changed or disappeared.

    python benchmarks/fuzz_inputs.py --seed 0 --cases 12        # cases per family (bags: per mutation kind)

Prints a table of counts per family and class, and the tracebacks found. ``tests/project/test_fuzz_bags.py`` runs a fixed
in-process subset (:func:`make_bag_cases`, :func:`run_in_process`).
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CLASSES = ("clean error", "ran", "ran, damage counted", "TRACEBACK", "HANG", ">2 GB", "LOST FILE")
#: address-space limit of one case's process (bytes)
MEMORY_LIMIT_BYTES = 2 * 2**30
#: one case's time limit (s): a quick dive runs in a few seconds
TIMEOUT_S = 90.0
BAG_MUTATIONS = ("truncate", "bitflip", "zero_block", "lying_header", "stamp_game")
STAMP_GAMES = ("reversed_imu", "huge_imu_stamp", "zero_imu_stamps", "future_dvl", "old_scan", "nan_point_times",
               "duplicate_stamps")


@dataclass
class Case:
    """One fuzz case: ``call`` is ``(function, *args)`` run by :func:`run_in_process`; ``argv`` the CLI's arguments
    (bags); ``inputs`` the files that must survive unchanged."""

    family: str
    name: str
    call: tuple
    argv: list[str] | None = None
    inputs: list[Path] = field(default_factory=list)


# ---------------------------------------------------------------------------------------------- base inputs
def base_dive(root: Path, *, seed: int = 0, scans: bool = True):
    """A quick simulated dive (a few scans) and its bags: ``root/ros1/dive.bag`` and ``root/mcap/dive`` (ROS 2
    MCAP), each with the companion files the recorder leaves beside it. Returns (dataset, {fmt: bag path})."""
    from semslam.dataset.rosbag_write import write_bag
    from semslam.simulation import SimulatorConfig, simulate_dataset

    ds = simulate_dataset(SimulatorConfig.quick(), seed=seed, with_scans=scans, scan_interval_s=4.0)
    bags = {}
    for fmt, rel in (("ros1", "ros1/dive.bag"), ("ros2-mcap", "mcap/dive")):
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bag(ds, path, fmt, overwrite=True)
        write_companions(ds, path)
        bags[fmt] = path
    return ds, bags


def write_companions(ds, bag: Path, topic_map=None) -> None:
    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import topic_map_of

    write_vehicle_toml(ds.vehicle, bag.with_name(bag.name + ".vehicle.toml"))
    bag.with_name(bag.name + ".topics.toml").write_text((topic_map or topic_map_of(ds)).to_toml())


def storage_file(bag: Path) -> Path:
    """The file holding a bag's records: the ``.bag`` itself, or a ROS 2 directory's ``.mcap``/``.db3``."""
    return next(p for p in sorted(bag.iterdir()) if p.suffix in (".mcap", ".db3")) if bag.is_dir() else bag


def copy_bag(bag: Path, dst_dir: Path) -> Path:
    """A copy of ``bag`` and its companion files in ``dst_dir``."""
    dst_dir.mkdir(parents=True, exist_ok=True)
    out = dst_dir / bag.name
    (shutil.copytree if bag.is_dir() else shutil.copy2)(bag, out)
    for what in ("vehicle", "topics"):
        c = bag.with_name(f"{bag.name}.{what}.toml")
        if c.exists():
            shutil.copy2(c, dst_dir / c.name)
    return out


# ---------------------------------------------------------------------------------------------- bag mutations
def mutate_bag_bytes(bag: Path, kind: str, rng: np.random.Generator) -> str:
    """Damage ``bag`` (a copy) in place; returns a description."""
    f = storage_file(bag)
    data = bytearray(f.read_bytes())
    n = len(data)
    if kind == "truncate":
        cut = int(n * float(rng.uniform(0.02, 0.999)))
        f.write_bytes(data[:cut])
        return f"cut at {cut} of {n} bytes"
    if kind == "bitflip":
        k = int(rng.integers(1, 17))
        for pos in rng.integers(0, n, size=k):
            data[int(pos)] ^= 1 << int(rng.integers(8))
        f.write_bytes(data)
        return f"{k} bits flipped"
    if kind == "zero_block":
        size = int(rng.choice([512, 4096, 65536]))
        off = int(rng.integers(0, max(n - size, 1)))
        data[off:off + size] = bytes(len(data[off:off + size]))
        f.write_bytes(data)
        return f"{size} bytes zeroed at {off}"
    if kind == "lying_header":
        return _lie(bag, f, data, rng)
    raise ValueError(kind)


def _lie(bag: Path, f: Path, data: bytearray, rng: np.random.Generator) -> str:
    """A header that lies: a count, offset or size field replaced by a huge, zero or random value."""
    value = int(rng.choice([0, 1, 2**31 - 1, 2**32 - 1, int(rng.integers(0, 2**32))]))
    if f.suffix == ".bag":
        keys = [b"index_pos=", b"conn_count=", b"chunk_count=", b"count=", b"size=", b"ver="]
        key = keys[int(rng.integers(len(keys)))]
        hits = [i for i in range(len(data)) if data.startswith(key, i)][:200] if key != b"count=" else \
            _find_all(data, key, 200)
        if not hits:
            return "no field to lie about"
        i = int(rng.choice(hits)) + len(key)
        width = 8 if key == b"index_pos=" else 4
        data[i:i + width] = (value % 2 ** (8 * width)).to_bytes(width, "little")
        f.write_bytes(data)
        return f"{key.decode()}{value}"
    which = int(rng.integers(3))
    if which == 0 and (bag / "metadata.yaml").exists():  # metadata.yaml's counts and times
        text = (bag / "metadata.yaml").read_text()
        keys = ("message_count: ", "nanoseconds: ", "nanoseconds_since_epoch: ")
        hits = [(i, k) for k in keys for i in _find_all(bytearray(text.encode()), k.encode(), 50)]
        i, k = hits[int(rng.integers(len(hits)))] if hits else (0, "")
        if k:  # one occurrence (a topic's count, the bag's duration or start) replaced
            end = text.find("\n", i)
            v = value if rng.random() < 0.7 else -value
            text = text[:i + len(k)] + str(v) + text[end if end >= 0 else len(text):]
        (bag / "metadata.yaml").write_text(text)
        return f"metadata.yaml {k.strip()} {value}"
    if which == 1:  # the footer's summary offsets
        off = len(data) - 37 + 9 + 8 * int(rng.integers(2))
        data[off:off + 8] = value.to_bytes(8, "little")
        f.write_bytes(data)
        return f"footer summary offset {value}"
    hits = _find_all(data, b"\x06", 2000)  # a chunk record's length / sizes (op 0x06 then a uint64 length)
    i = int(rng.choice(hits)) if hits else 8
    data[i + 1:i + 9] = value.to_bytes(8, "little")
    f.write_bytes(data)
    return f"record length at {i} = {value}"


def _find_all(data: bytearray, key: bytes, limit: int) -> list[int]:
    out, i = [], data.find(key)
    while i >= 0 and len(out) < limit:
        out.append(i)
        i = data.find(key, i + 1)
    return out


def stamp_game_bag(ds, path: Path, game: str, fmt: str = "ros1", rng: np.random.Generator | None = None) -> Path:
    """Write ``ds`` as a bag whose header stamps play ``game`` (see :data:`STAMP_GAMES`); bag receive times stay
    those of the recorder. ``reversed_imu``: the IMU's stamps in reverse order; ``huge_imu_stamp``: one IMU stamp at
    2^31 - 1 s; ``zero_imu_stamps``: every IMU header stamp zero (the receive time is used); ``future_dvl``: the
    DVL's stamps 100 s ahead; ``old_scan``: one scan stamped 100 s before the bag starts; ``nan_point_times``: a
    scan's per-point times NaN; ``duplicate_stamps``: every depth message twice."""
    from rosbags.typesys import get_types_from_msg

    from semslam.dataset.rosbag_write import DVL_MSG, DVL_TYPE, _messages
    from semslam.io.ros._encode import default_typestore

    rng = np.random.default_rng(0) if rng is None else rng
    ros1 = fmt == "ros1"
    store = default_typestore(ros1=ros1)
    store.register(get_types_from_msg(DVL_MSG, DVL_TYPE))
    if "tf2_msgs/msg/TFMessage" not in store.types:
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
    msgs = list(_messages(ds, store, store.types))
    T = store.types

    def stamped(msg, ns: int):
        sec, nsec = divmod(int(ns), 1_000_000_000)
        stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        return dataclasses.replace(msg, header=dataclasses.replace(msg.header, stamp=stamp))

    imu = [i for i, m in enumerate(msgs) if m[1] == "/semslam/imu"]
    out = list(msgs)
    if game == "reversed_imu":
        for i, j in zip(imu, imu[::-1]):
            out[i] = (msgs[i][0], msgs[i][1], msgs[i][2], stamped(msgs[i][3], msgs[j][0]))
    elif game == "huge_imu_stamp":
        i = imu[int(rng.integers(len(imu)))]
        out[i] = (*msgs[i][:3], stamped(msgs[i][3], (2**31 - 1) * 1_000_000_000))
    elif game == "zero_imu_stamps":
        out = [(*m[:3], stamped(m[3], 0)) if m[1] == "/semslam/imu" else m for m in msgs]
    elif game == "future_dvl":
        out = [(*m[:3], stamped(m[3], m[0] + 100 * 10**9)) if m[1] == "/semslam/dvl" else m for m in msgs]
    elif game == "old_scan":
        scans = [i for i, m in enumerate(msgs) if m[1] == "/semslam/scans"] or imu
        i = scans[int(rng.integers(len(scans)))]
        out[i] = (*msgs[i][:3], stamped(msgs[i][3], msgs[0][0] - 100 * 10**9))
    elif game == "nan_point_times":
        scans = [i for i, m in enumerate(msgs) if m[1] == "/semslam/scans"]
        for i in scans[:1]:
            m = msgs[i][3]
            fld = next(f for f in m.fields if f.name == "t")
            data = np.array(m.data, dtype=np.uint8).reshape(-1, m.point_step)
            data[:, fld.offset:fld.offset + 8] = np.frombuffer(np.float64(np.nan).tobytes(), np.uint8)
            out[i] = (*msgs[i][:3], dataclasses.replace(m, data=data.reshape(-1)))
    elif game == "duplicate_stamps":
        out = [x for m in msgs for x in ((m, m) if m[1] == "/semslam/pressure" else (m,))]
    else:
        raise ValueError(game)
    if ros1:
        from rosbags.rosbag1 import Writer

        with Writer(path) as writer:
            conns = {}
            for ns, topic, mt, msg in out:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, mt, typestore=store)
                writer.write(conns[topic], ns, store.serialize_ros1(msg, mt))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conns = {}
            for ns, topic, mt, msg in out:
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, mt, typestore=store)
                writer.write(conns[topic], ns, store.serialize_cdr(msg, mt))
    return path


def make_bag_cases(ds, bags: dict, work: Path, *, seed: int, per_kind: int,
                   kinds: tuple = BAG_MUTATIONS) -> list[Case]:
    """``per_kind`` seeded cases of each mutation kind, alternating ROS 1 and ROS 2 MCAP bags."""
    rng = np.random.default_rng(seed)
    cases = []
    for kind in kinds:
        for k in range(per_kind):
            fmt = ("ros1", "ros2-mcap")[k % 2]
            d = work / f"bag_{kind}_{k}"
            shutil.rmtree(d, ignore_errors=True)
            if kind == "stamp_game":
                game = STAMP_GAMES[k % len(STAMP_GAMES)]
                d.mkdir(parents=True)
                bag = stamp_game_bag(ds, d / ("dive.bag" if fmt == "ros1" else "dive"), game, fmt, rng)
                write_companions(ds, bag)
                what = game
            else:
                bag = copy_bag(bags[fmt], d)
                what = mutate_bag_bytes(bag, kind, rng)
            inputs = [p for p in ([bag] if bag.is_file() else sorted(bag.iterdir()))]
            inputs += [bag.with_name(bag.name + ".vehicle.toml"), bag.with_name(bag.name + ".topics.toml")]
            cases.append(Case("bag", f"{fmt} {kind}: {what}", ("read_dive", str(bag)),
                              ["run", str(bag), "--db", "builtin", "--mode", "dr", "--no-report", "--json",
                               "--out", str(d / "run")], inputs))
    return cases


# ---------------------------------------------------------------------------------------------- TOML and models
def mutate_text(data: bytes, rng: np.random.Generator) -> bytes:
    """One seeded mutation of a TOML file: bytes flipped, the file cut, lines swapped or dropped, a number made
    absurd, a value retyped, a table nested very deep, a key duplicated, a huge string."""
    kind = int(rng.integers(10))
    lines = data.split(b"\n")
    if kind == 0 and data:
        b = bytearray(data)
        for i in rng.integers(0, len(b), size=int(rng.integers(1, 8))):
            b[int(i)] = int(rng.integers(0, 256))
        return bytes(b)
    if kind == 1:
        return data[: int(rng.integers(0, max(len(data), 1)))]
    if kind == 2 and len(lines) > 2:
        i, j = (int(v) for v in rng.integers(1, len(lines), size=2))
        lines[i], lines[j] = lines[j], lines[i]
        return b"\n".join(lines)
    if kind in (3, 4):
        words = data.replace(b"=", b" = ").replace(b",", b" , ").split(b" ")
        idx = [k for k, w in enumerate(words) if w.strip().replace(b".", b"").replace(b"-", b"").isdigit()]
        if idx:
            words[int(rng.choice(idx))] = [b"1e308", b"nan", b"-1e9", b"inf", b"0", b'"x"', b"true", b"1e-300",
                                           b"-0.0", b"9" * 40][int(rng.integers(10))]
            return b" ".join(words).replace(b" = ", b"=").replace(b" , ", b",")
    if kind == 5 and len(lines) > 1:
        del lines[int(rng.integers(len(lines)))]
        return b"\n".join(lines)
    if kind == 6:
        depth = int(rng.choice([100, 5000]))
        return data + b"\nnested = " + b"[" * depth + b"1" + b"]" * depth + b"\n"
    if kind == 7 and len(lines) > 1:
        line = next((l for l in lines if b"=" in l), b"x = 1")
        return data + b"\n" + line + b"\n"
    if kind == 8:
        return data + b'\nhuge = "' + b"A" * int(rng.choice([10_000, 2_000_000])) + b'"\n'
    return data.replace(b'"', b"'", 1).replace(b"[", b"{", 1)


def base_toml_files(ds, root: Path) -> dict[str, Path]:
    """A valid topic map, vehicle file and run configuration (every key of the defaults)."""
    from semslam.dataset import write_vehicle_toml
    from semslam.dataset.rosbag_write import topic_map_of
    from semslam.run.config import load_run_config, write_resolved_config

    root.mkdir(parents=True, exist_ok=True)
    (root / "topics.toml").write_text(topic_map_of(ds).to_toml())
    write_vehicle_toml(ds.vehicle, root / "vehicle.toml")
    cfg = root / "cfg"
    cfg.mkdir(exist_ok=True)
    write_resolved_config(load_run_config(), cfg)
    shutil.copy2(cfg / "config.toml", root / "config.toml")
    return {"topic map": root / "topics.toml", "vehicle": root / "vehicle.toml", "run config": root / "config.toml"}


def make_toml_cases(files: dict, work: Path, *, seed: int, per_kind: int) -> list[Case]:
    calls = {"topic map": "read_topic_map", "vehicle": "read_vehicle_toml", "run config": "load_run_config"}
    rng = np.random.default_rng(seed + 1)
    cases = []
    for family, src in files.items():
        for k in range(per_kind):
            d = work / f"{family.replace(' ', '_')}_{k}"
            d.mkdir(parents=True, exist_ok=True)
            p = d / src.name
            p.write_bytes(mutate_text(src.read_bytes(), rng))
            cases.append(Case(family, f"{family} #{k}", (calls[family], str(p)), None, [p]))
    return cases


def make_model_cases(models_dir: Path, work: Path, *, seed: int, per_kind: int) -> list[Case]:
    """Model folders: models.toml mutated; a mesh cut, bit-flipped or replaced; a file path outside the folder
    (absolute, ``../``, a symlink); a mesh that is a directory."""
    rng = np.random.default_rng(seed + 2)
    cases = []
    for k in range(per_kind):
        d = work / f"models_{k}"
        shutil.rmtree(d, ignore_errors=True)
        shutil.copytree(models_dir, d, ignore=shutil.ignore_patterns("*.py"))
        kind = k % 6
        meshes = sorted(d.glob("*.stl"))
        if kind in (0, 1):
            (d / "models.toml").write_bytes(mutate_text((d / "models.toml").read_bytes(), rng))
            what = "models.toml mutated"
        elif kind == 2:
            m = meshes[int(rng.integers(len(meshes)))]
            b = m.read_bytes()
            m.write_bytes(b[: int(len(b) * float(rng.uniform(0.0, 0.99)))])
            what = f"{m.name} cut"
        elif kind == 3:
            m = meshes[int(rng.integers(len(meshes)))]
            b = bytearray(m.read_bytes())
            for pos in rng.integers(0, len(b), size=int(rng.integers(1, 64))):
                b[int(pos)] = int(rng.integers(256))
            if rng.random() < 0.5:  # the binary STL's triangle count lies
                b[80:84] = int(rng.choice([0, 2**31 - 1, 2**32 - 1])).to_bytes(4, "little")
            m.write_bytes(bytes(b))
            what = f"{m.name} bytes flipped"
        elif kind == 4:
            t = (d / "models.toml").read_text()
            target = ["/etc/hostname", "../elsewhere.stl", "link.stl"][int(rng.integers(3))]
            if target == "link.stl":
                (d / "link.stl").symlink_to("/etc/hostname")
            (d.parent / "elsewhere.stl").write_bytes(meshes[0].read_bytes())
            t = t.replace(f'file = "{meshes[0].name}"', f'file = "{target}"', 1)
            (d / "models.toml").write_text(t)
            what = f"a path outside the folder ({target})"
        else:
            m = meshes[int(rng.integers(len(meshes)))]
            m.unlink()
            m.mkdir()
            what = f"{m.name} is a directory"
        inputs = [p for p in sorted(d.iterdir()) if p.is_file() and not p.is_symlink()]
        cases.append(Case("models", f"models #{k}: {what}", ("read_models", str(d)), None, inputs))
    return cases


# ---------------------------------------------------------------------------------------------- running a case
def run_in_process(case: Case) -> str:
    """Run ``case.call`` in this process: "clean error" (a SemslamError), "ran", "ran, damage counted"; anything
    else propagates (a traceback). Hangs and memory are the caller's to bound (:func:`run_subprocess`)."""
    import warnings

    from semslam.errors import SemslamError

    name, *args = case.call
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return _CALLS[name](*args)
    except SemslamError as err:
        if "\n" in str(err).strip() and not str(err).startswith("The frame of the DVL topic"):
            raise AssertionError(f"a multi-line error: {err}") from None
        return "clean error"


def _read_dive(path: str) -> str:
    """Open the dive as ``semslam run`` does, read every message and judge the source's counts."""
    from semslam.run.damage import add_damage_checks
    from semslam.run.health import Verdict
    from semslam.run.sources import open_dive

    dive = open_dive(path)
    for _ in dive.messages():
        pass
    v = Verdict()
    add_damage_checks(v, dive.counts)
    return "ran, damage counted" if v.checks else "ran"


def _read_topic_map(p):
    from semslam.dataset.rosbag import read_topic_map

    read_topic_map(p)
    return "ran"


def _read_vehicle(p):
    from semslam.dataset import read_vehicle_toml

    read_vehicle_toml(p)
    return "ran"


def _load_run_config(p):
    from semslam.run.config import load_run_config

    load_run_config(p)
    return "ran"


def _read_models(p):
    from semslam.simulation.cad_models import read_models

    read_models(p)
    return "ran"


_CALLS = {"read_dive": _read_dive, "read_topic_map": _read_topic_map, "read_vehicle_toml": _read_vehicle,
          "load_run_config": _load_run_config, "read_models": _read_models}


def _digest(paths) -> dict[str, str | None]:
    out = {}
    for p in paths:
        p = Path(p)
        out[str(p)] = hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else None
    return out


def _limit_memory() -> None:
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT_BYTES, MEMORY_LIMIT_BYTES))
    os.nice(10)


def run_subprocess(case: Case, *, timeout_s: float = TIMEOUT_S) -> tuple[str, str]:
    """Run one case in a child process (the CLI for a bag, the library call otherwise) under the memory limit and
    the timeout; returns (class, detail)."""
    before = _digest(case.inputs)
    if case.argv is not None:
        code = ("import sys; from semslam.cli.main import main; sys.exit(main(sys.argv[1:]))")
        cmd = [sys.executable, "-c", code, *case.argv]
    else:
        code = ("import json, sys; sys.path.insert(0, sys.argv[1]); import fuzz_inputs as f; "
                "print('CLASS=' + f.run_in_process(f.Case('', '', tuple(json.loads(sys.argv[2])))))")
        cmd = [sys.executable, "-c", code, str(Path(__file__).parent), json.dumps(list(case.call))]
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, preexec_fn=_limit_memory,
                           env={**os.environ, "PYTHONWARNINGS": "ignore"})
    except subprocess.TimeoutExpired:
        return "HANG", f"> {timeout_s:.0f} s"
    after = _digest(case.inputs)
    if after != before:
        lost = [k for k in before if after.get(k) != before[k]]
        return "LOST FILE", ", ".join(lost)
    err = r.stderr.strip()
    if "MemoryError" in err or r.returncode in (-9, -6) or "Cannot allocate memory" in err:
        return ">2 GB", err[-300:]
    if "Traceback (most recent call last)" in err:
        return "TRACEBACK", err.splitlines()[-1][:300]
    if case.argv is None:
        if "CLASS=" in r.stdout and r.returncode == 0:
            return r.stdout.split("CLASS=")[-1].strip(), ""
        return "TRACEBACK", (err or r.stdout)[-300:]
    if r.returncode in (0, 3):
        try:
            payload = json.loads(r.stdout)
        except ValueError:
            return "TRACEBACK", "no JSON on stdout: " + r.stdout[-200:]
        checks = [c for res in (payload.get("health") or {}).values() if isinstance(res, dict)
                  for c in res.get("checks", [])] if isinstance(payload.get("health"), dict) else []
        damaged = any(c.get("check") in ("damaged recording", "stream order") for c in checks) or \
            "damaged recording" in r.stdout or "stream order" in r.stdout
        return ("ran, damage counted" if damaged else "ran"), ""
    lines = [l for l in err.splitlines() if l.strip()]
    if r.returncode in (1, 2) and lines and lines[-1].startswith("semslam"):
        return "clean error", lines[-1][:200]
    return "TRACEBACK", f"exit {r.returncode}: {err[-300:]}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", type=int, default=8, help="cases per family (bags: per mutation kind)")
    ap.add_argument("--budget-s", type=float, default=1800.0, help="stop starting cases after this time")
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one, removed)")
    ap.add_argument("--families", default="bag,toml,models")
    args = ap.parse_args(argv)
    import tempfile

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="semslam-fuzz-"))
    try:
        t0 = time.perf_counter()
        ds, bags = base_dive(work / "base", seed=args.seed)
        fams = args.families.split(",")
        cases: list[Case] = []
        if "bag" in fams:
            cases += make_bag_cases(ds, bags, work / "cases", seed=args.seed, per_kind=args.cases)
        if "toml" in fams:
            cases += make_toml_cases(base_toml_files(ds, work / "toml"), work / "cases", seed=args.seed,
                                     per_kind=args.cases)
        if "models" in fams:
            models = Path(__file__).resolve().parent.parent / "tests" / "data" / "models"
            cases += make_model_cases(models, work / "cases", seed=args.seed, per_kind=args.cases)
        table: dict[str, dict[str, int]] = {}
        problems = []
        for i, case in enumerate(cases):
            if time.perf_counter() - t0 > args.budget_s:
                print(f"time budget reached after {i} of {len(cases)} cases", file=sys.stderr)
                break
            cls, detail = run_subprocess(case)
            table.setdefault(case.family, dict.fromkeys(CLASSES, 0))[cls] += 1
            if cls not in ("clean error", "ran", "ran, damage counted"):
                problems.append((case.family, case.name, cls, detail))
            print(f"[{i + 1}/{len(cases)}] {case.family}: {case.name}: {cls} {detail[:120]}", file=sys.stderr)
        print(f"| family | {' | '.join(CLASSES)} |")
        print("|---" * (len(CLASSES) + 1) + "|")
        for fam, row in table.items():
            print(f"| {fam} | {' | '.join(str(row[c]) for c in CLASSES)} |")
        tot = {c: sum(r[c] for r in table.values()) for c in CLASSES}
        print(f"| all | {' | '.join(str(tot[c]) for c in CLASSES)} |")
        print(f"seed {args.seed}, {sum(tot.values())} cases, {time.perf_counter() - t0:.0f} s")
        for p in problems:
            print("PROBLEM:", *p)
        return 1 if problems else 0
    finally:
        if not args.work:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
