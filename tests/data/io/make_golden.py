"""Regenerate the golden PCD files of tests/test_io_*.py (run from the repository root):

    .venv/bin/python tests/data/io/make_golden.py [PATH_TO_pcl_ref]

``src_*.pcd`` are written by semslam (binary); ``pcl_*_{ascii,binary,binary_compressed}.pcd`` are the same
files rewritten by PCL 1.13 (``pcl_ref convert``). ``pad_binary.pcd`` is hand-made with ``_`` padding
fields. ``expected.npz`` holds the source arrays the tests compare against.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from semslam.io.pcd import PcdData, read_pcd, write_pcd

HERE = Path(__file__).resolve().parent
ENCODINGS = {"ascii": 0, "binary": 1, "binary_compressed": 2}


def sources() -> dict[str, PcdData]:
    rng = np.random.default_rng(0)
    n = 12  # organised 4 x 3
    xyz = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
    xyz[[2, 7]] = np.nan
    nrm = rng.normal(size=(n, 3)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    fields = {
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "normal_x": nrm[:, 0],
        "normal_y": nrm[:, 1],
        "normal_z": nrm[:, 2],
        "curvature": rng.uniform(0, 0.1, n).astype(np.float32),
        "rgb": rng.integers(0, 2**32, n, dtype=np.uint32).view(
            np.float32
        ),  # packed colour in a float
        "rgba": rng.integers(0, 2**32, n, dtype=np.uint32),
        "intensity": rng.uniform(0, 1000, n).astype(np.float32),
        "label": rng.integers(0, 2**32, n, dtype=np.uint32),
        "ring": rng.integers(0, 2**16, n, dtype=np.uint16),
        "flags": rng.integers(0, 256, n, dtype=np.uint8),
        "offset": rng.integers(-(2**15), 2**15, n, dtype=np.int16),
        "tag": rng.integers(-128, 128, n, dtype=np.int8),
        "index": rng.integers(-(2**31), 2**31, n, dtype=np.int32),
        "time": rng.uniform(0, 1e9, n),  # float64
        "hist": rng.uniform(0, 1, (n, 5)).astype(np.float32),  # COUNT 5
    }
    organised = PcdData(
        fields, width=4, height=3, viewpoint=np.array([1.0, 2.0, 3.0, 0.0, 1.0, 0.0, 0.0])
    )
    sig = {"vfh": (rng.uniform(0, 100, (2, 308)).astype(np.float32))}
    vfh = PcdData(sig, width=2, height=1)
    esf = PcdData({"esf": rng.uniform(0, 1, (1, 640)).astype(np.float32)}, width=1, height=1)
    return {"fields": organised, "vfh": vfh, "esf": esf}


def pad_file() -> bytes:
    """x y z with a 2-byte and a 4-byte ``_`` padding field, binary, 3 points."""
    head = (
        b"# .PCD v0.7\nVERSION 0.7\nFIELDS x _ y z _\nSIZE 4 1 4 4 4\nTYPE F U F F F\nCOUNT 1 2 1 1 1\n"
        b"WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA binary\n"
    )
    body = b""
    for i in range(3):
        body += (
            np.float32(i + 0.25).tobytes()
            + b"\xaa\xbb"
            + np.array([i * 2.0, -i], np.float32).tobytes()
        )
        body += b"\xde\xad\xbe\xef"
    return head + body


def main(pcl_ref: str) -> None:
    arrays = {}
    for name, data in sources().items():
        src = HERE / f"src_{name}.pcd"
        write_pcd(src, data, encoding="binary")
        for k, v in data.fields.items():
            arrays[f"{name}/{k}"] = v
        for enc, code in ENCODINGS.items():
            out = HERE / f"pcl_{name}_{enc}.pcd"
            subprocess.run(
                [pcl_ref, "convert", str(src), str(out), str(code)], check=True, capture_output=True
            )
            read_pcd(out)
    np.savez(HERE / "expected.npz", **arrays)
    (HERE / "pad_binary.pcd").write_bytes(pad_file())
    for path in HERE.glob("*.pcd"):  # atomic writes create 0600 files (mkstemp)
        path.chmod(0o644)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else str(Path.home() / ".cache/pcl_oracle/pcl_ref"))
