"""Copies move the right bytes; timestamps sit on the host clock and grow with the work;
semaphores order work; simulated GPUs are separate instances."""
from __future__ import annotations

import time

import numpy as np
import pytest

from mgpusim.real.host.memcpy import MIN_CHUNK, HostCopier
from mgpusim.real.passes.standalone import FragmentLoop, Mesh
from mgpusim.real.vulkan.copies import CopyD2D, CopyD2H, CopyH2D, copy_image_to_buffer, download, upload
from mgpusim.real.vulkan.machine import close_gpus, make_gpus

pytestmark = pytest.mark.vulkan


def test_h2d_then_d2h_round_trip(gpu):
    h2d = CopyH2D(gpu, 64 * 1024, queue="transfer")  # falls back to graphics on lavapipe
    d2h = CopyD2H(gpu, 64 * 1024)
    pattern = np.random.default_rng(0).integers(0, 256, h2d.bytes, dtype=np.uint8)
    h2d.buffer.array[:] = pattern
    gpu.run(h2d.queue, h2d.record)
    gpu.run("graphics", lambda cmd: copy_image_to_buffer(cmd, h2d.image, d2h.buffer))
    assert np.array_equal(d2h.buffer.array, pattern)
    h2d.destroy()
    d2h.destroy()


def test_d2d_copies_buffer(gpu):
    c = CopyD2D(gpu, 10_000)
    data = np.arange(10_000, dtype=np.uint32).astype(np.uint8)
    upload(gpu, c.src, data)
    gpu.run(c.queue, c.record)
    assert np.array_equal(download(gpu, c.dst), data)
    c.destroy()


def test_host_copy_chunks_and_content():
    copier = HostCopier(3)
    assert all(b - a >= MIN_CHUNK for a, b in copier.chunks(4 * MIN_CHUNK)[:-1])
    assert len(copier.chunks(100)) == 1
    src = np.random.default_rng(0).integers(0, 256, 3 * MIN_CHUNK + 5, dtype=np.uint8)
    dst = np.zeros_like(src)
    start, end = copier.copy(dst, src)
    assert np.array_equal(dst, src) and end >= start
    copier.close()


def test_timestamps_are_host_monotonic_ns(gpu):
    p = FragmentLoop(gpu, 16, 16, 10)
    before = time.monotonic_ns()
    sub = gpu.submit("graphics", p.record)
    start, end = sub.wait().timestamps_ns()
    after = time.monotonic_ns()
    assert before <= start <= end <= after
    assert sub.duration_ns == end - start
    p.destroy()


def _fastest(gpu, work, reps=5, warmup=10):
    """Fastest of `reps` runs after `warmup` untimed ones: interference from other processes
    only adds time, and lavapipe's mesh path gets faster over its first ~10 draws."""
    for _ in range(warmup):
        gpu.run(work.queue, work.record)
    return min(gpu.run(work.queue, work.record).duration_ns for _ in range(reps))


def _ratio(gpu, small, big):
    try:
        return _fastest(gpu, small), _fastest(gpu, big)
    finally:  # destroyed even when the timing assertion fails, so the layer reports no leak
        small.destroy()
        big.destroy()


def test_ten_times_iterations_take_clearly_longer(gpu):
    t_small, t_big = _ratio(gpu, FragmentLoop(gpu, 64, 64, 300), FragmentLoop(gpu, 64, 64, 3000))
    assert t_big > 3 * t_small, (t_small, t_big)


def test_ten_times_triangles_take_clearly_longer(gpu):
    t_small, t_big = _ratio(gpu, Mesh(gpu, 64, 64, 3000), Mesh(gpu, 64, 64, 30000))
    assert t_big > 3 * t_small, (t_small, t_big)


def test_semaphore_orders_submissions(gpu):
    a, b = FragmentLoop(gpu, 32, 32, 2000), FragmentLoop(gpu, 16, 16, 1)
    sem = gpu.semaphore()
    first = gpu.submit("graphics", a.record, signal=[sem])
    second = gpu.submit("graphics", b.record, wait=[sem])
    assert second.wait().timestamps_ns()[0] >= first.wait().timestamps_ns()[1]
    a.destroy()
    b.destroy()


def test_keyed_submissions_record_once_and_still_do_the_work(gpu):
    """A key's command buffer is recorded once and submitted again; each submission runs the
    work (new data is copied, new timestamps are read) and two keys never share a buffer."""
    c = CopyD2D(gpu, 4096)
    recorded = []

    def record(cmd):
        recorded.append(1)
        c.record(cmd)

    spans = []
    for value in (1, 2, 3):
        upload(gpu, c.src, np.full(4096, value, dtype=np.uint8))
        spans.append(gpu.submit(c.queue, record, key="copy").wait().timestamps_ns())
        assert np.all(download(gpu, c.dst) == value)
    assert len(recorded) == 1
    assert spans[0][1] <= spans[1][0] and spans[1][1] <= spans[2][0]
    gpu.submit(c.queue, record, key="other").wait()
    assert len(recorded) == 2
    gpu.forget("copy")  # before the work it drew is destroyed: recorded afresh if used again
    gpu.submit(c.queue, record, key="copy").wait()
    assert len(recorded) == 3
    gpu.forget("copy")
    gpu.forget("other")
    c.destroy()


def test_finished_sees_the_end_of_a_task_with_more_work_queued_behind_it(gpu):
    """On lavapipe a fence wait returns only when the queue is idle; `finished` must report A's
    end while B (queued behind it) still runs, as a GPU's fence would."""
    a, b = FragmentLoop(gpu, 64, 64, 3000), FragmentLoop(gpu, 64, 64, 3000)
    first = gpu.submit("graphics", a.record)
    second = gpu.submit("graphics", b.record)
    assert second.done() is False  # queued behind A: a pending fence is "not done", no error
    while not first.finished(1_000_000):
        pass
    seen = time.monotonic_ns()
    a_end = first.wait().timestamps_ns()[1]
    b_end = second.wait().timestamps_ns()[1]
    assert a_end <= seen < b_end and second.done() is True
    a.destroy()
    b.destroy()


def test_reading_a_tasks_timestamps_does_not_wait_for_the_work_behind_it(gpu):
    """Lavapipe's vkGetQueryPoolResults waits for the device to go idle: a reap thread reading
    task A's timestamps that way waited for B too, and a busy GPU's slots came back frames late.
    The command buffer copies its stamps to mapped memory instead: reading them is immediate."""
    a, b = FragmentLoop(gpu, 64, 64, 300), FragmentLoop(gpu, 64, 64, 30000)
    try:
        first = gpu.submit("graphics", a.record)
        second = gpu.submit("graphics", b.record)
        while not first.finished(1_000_000):
            pass
        a_start, a_end = first.wait().timestamps_ns()  # reads the stamps, recycles the slot
        running = not second.poll()  # B still runs: the read did not wait for it
        b_start, _ = second.wait().timestamps_ns()
        assert running and a_start < a_end <= b_start
    finally:  # destroyed even when an assertion fails, so the layer reports no leak
        gpu.wait_idle()
        a.destroy()
        b.destroy()


def test_simulated_gpus_are_separate_instances_with_thread_counts():
    gpus = make_gpus(2, lp_threads=[1, 2])
    try:
        assert gpus[0].instance is not gpus[1].instance
        assert [g.instance.lp_num_threads for g in gpus] == [1, 2]
        works = [FragmentLoop(g, 32, 32, 500) for g in gpus]
        subs = [g.submit("graphics", w.record) for g, w in zip(gpus, works)]
        spans = [s.wait().timestamps_ns() for s in subs]
        assert all(e > s for s, e in spans)
        for w in works:
            w.destroy()
    finally:
        close_gpus(gpus)


def test_several_threads_waiting_for_one_task_all_see_its_end(gpu):
    """Threads waiting for the same task (three GPUs waiting for GPU 0's present): one of them
    watches the fence, the others wait on it; all see the end, and the slot is recycled only
    once the watcher has left the fence wait."""
    import threading

    long = FragmentLoop(gpu, 256, 256, 20000)
    sub = gpu.submit("graphics", long.record)
    seen: list[int] = []
    threads = [threading.Thread(target=lambda: seen.append(sub.finished(30_000_000_000) and
                                                           time.monotonic_ns()))
               for _ in range(4)]
    for t in threads:
        t.start()
    deadline = time.monotonic() + 5
    while not sub._watched and time.monotonic() < deadline and not sub.poll():
        time.sleep(0.001)
    for t in threads:
        t.join(30)
    assert len(seen) == 4 and all(seen)
    start, end = sub.wait().timestamps_ns()
    assert not sub._watched and sub._slot is None and min(seen) >= end - 50_000
    long.destroy()
