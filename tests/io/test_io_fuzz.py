"""Property-based robustness of the PCD reader: mutated valid files (byte flips, truncation, header edits)
either read into arrays of the declared size or raise a SemslamError (PcdError), never anything else."""

from __future__ import annotations

import tempfile
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from semslam.errors import PcdError, SemslamError
from semslam.io.pcd import read_pcd, write_pcd

IO = Path(__file__).resolve().parents[1] / "data" / "io"
N_EXAMPLES = 600


def _seed_files() -> list[bytes]:
    src = read_pcd(IO / "src_fields.pcd")
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for enc in ("ascii", "binary", "binary_compressed"):
            write_pcd(Path(tmp) / "seed.pcd", src, encoding=enc)
            out.append((Path(tmp) / "seed.pcd").read_bytes())
    out += [
        (IO / name).read_bytes()
        for name in ("pad_binary.pcd", "pcl_fields_binary_compressed.pcd", "pcl_fields_ascii.pcd")
    ]
    return out


SEEDS = _seed_files()
TOKENS = [
    "0",
    "1",
    "2",
    "-1",
    "3",
    "12",
    "13",
    "999999999",
    "4294967297",
    "x",
    "nan",
    "inf",
    "1.5",
    "",
    "F",
    "U",
    "I",
    "8",
    "ascii",
    "binary",
    "binary_compressed",
    "_",
    "rgb",
    "\xff",
    "1e3",
    "0 0",
]


@st.composite
def mutated(draw) -> bytes:
    data = bytearray(draw(st.sampled_from(SEEDS)))
    header_end = data.index(b"\nDATA") + 1
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(
            st.sampled_from(["flip", "flip_body", "truncate", "edit", "drop_line", "insert"])
        )
        if kind in ("flip", "flip_body") and data:
            lo = header_end if kind == "flip_body" and header_end < len(data) else 0
            pos = draw(st.integers(lo, len(data) - 1))
            data[pos] = draw(st.integers(0, 255))
        elif kind == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif kind == "insert":
            pos = draw(st.integers(0, len(data)))
            data[pos:pos] = draw(st.binary(min_size=1, max_size=8))
        else:
            lines = bytes(data[:header_end]).split(b"\n")
            i = draw(st.integers(0, len(lines) - 1))
            if kind == "drop_line":
                del lines[i]
            else:
                words = lines[i].split(b" ")
                j = draw(st.integers(0, len(words) - 1))
                words[j] = draw(st.sampled_from(TOKENS)).encode("utf-8")
                lines[i] = b" ".join(words)
            data = bytearray(b"\n".join(lines)) + data[header_end:]
        header_end = min(header_end, len(data))
    return bytes(data)


def test_mutated_files_raise_only_pcd_error(tmp_path):
    outcomes: Counter = Counter()
    path = tmp_path / "fuzz.pcd"

    @settings(
        max_examples=N_EXAMPLES,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    )
    @given(content=mutated())
    def check(content: bytes) -> None:
        path.write_bytes(content)
        try:
            data = read_pcd(path)
        except PcdError as exc:
            assert "fuzz.pcd" in str(exc)
            outcomes["PcdError"] += 1
            return
        n = data.width * data.height
        assert data.n_points == n and data.valid_mask.shape == (n,)
        declared = {f.name: f for f in data.file_fields if not f.is_padding}
        assert list(data.fields) == list(declared)
        for name, arr in data.fields.items():
            f = declared[name]
            assert arr.shape == ((n,) if f.count == 1 else (n, f.count)) and arr.dtype == f.dtype
        try:
            data.to_point_cloud()
            outcomes["read"] += 1
        except SemslamError:
            outcomes["read, not a cloud"] += 1

    check()
    print(f"\nPCD fuzz: {sum(outcomes.values())} mutated files: {dict(outcomes)}")
    assert sum(outcomes.values()) == N_EXAMPLES
    assert outcomes["PcdError"] > N_EXAMPLES // 4 and outcomes["read"] > N_EXAMPLES // 20
