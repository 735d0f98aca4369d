"""semslam._memory: the heap's free pages go back to the system after a scan (glibc), and nothing breaks
elsewhere."""

from __future__ import annotations

import platform

import numpy as np
import pytest

from semslam._memory import heap_free_bytes, release_free_memory


def _rss_anon_kb() -> int:
    for line in open("/proc/self/status", encoding="ascii"):
        if line.startswith("RssAnon:"):
            return int(line.split()[1])
    raise AssertionError("no RssAnon in /proc/self/status")


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_free_heap_pages_go_back_to_the_system_after_a_trim():
    """Many 200 kB blocks (below the mmap threshold once glibc raised it: heap memory), all freed but the last
    (which pins the top of the heap, as a long run's live arrays do): free() alone keeps the freed heap resident;
    release_free_memory() gives most of it back."""
    big = np.empty(40 << 20, dtype=np.uint8)  # freeing a block this large raises glibc's mmap threshold
    big[::4096] = 1
    del big
    blocks = [np.ones(200_000, dtype=np.uint8) for _ in range(400)]  # ~80 MB on the heap
    pin = blocks.pop()
    before = _rss_anon_kb()
    blocks.clear()
    assert _rss_anon_kb() > before - 20_000  # still resident: the heap below the pin is not trimmed by free()
    assert release_free_memory() is True
    after = _rss_anon_kb()
    assert before - after > 40_000, f"resident anonymous memory {before} kB -> {after} kB"
    assert pin[0] == 1


@pytest.mark.skipif(platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only")
def test_trim_waits_until_enough_of_the_heap_is_free():
    """With a threshold the heap is trimmed only when more than it is free (mallinfo2's free bytes), so a run does
    not give back, every scan, pages the next scan faults in again."""
    big = np.empty(40 << 20, dtype=np.uint8)
    big[::4096] = 1
    del big
    blocks = [np.ones(200_000, dtype=np.uint8) for _ in range(200)]  # ~40 MB on the heap
    pin = blocks.pop()
    blocks.clear()
    free = heap_free_bytes()
    assert free is not None and free > 30 << 20
    before = _rss_anon_kb()
    assert release_free_memory(above_bytes=free + (64 << 20)) is False  # not enough free: nothing done
    assert _rss_anon_kb() > before - 10_000
    assert release_free_memory(above_bytes=free // 2) is True
    assert before - _rss_anon_kb() > 20_000
    assert pin[0] == 1
