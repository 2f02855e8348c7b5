"""Frame pipelining: exact timelines, chunking, copy placement, peer path, no drift."""
from __future__ import annotations

import pytest

from mgpusim import InputError, simulate
from tests.schedule_helpers import assert_no_drift, experiment, gpu, presents, profile, rows, timed

PASSES = [timed("a", 1000, output_bytes=200), timed("b", 400, output_bytes=100), timed("c", 300)]


def run(fidelity="full", **kw):
    kw.setdefault("split_at", 2)
    kw.setdefault("fif", 3)
    kw.setdefault("warmup", 1)
    return simulate(experiment(kw.pop("prof", profile()), "pipelining", PASSES, **kw),
                    fidelity=fidelity)


def test_exact_timeline_per_pass_copies():
    """GPU 1: a 0-1000, b 1000-1400; a's 200 B cross 1000-1200-1400, b's 100 B 1400-1500-1600;
    GPU 0: c 1600-1900, present 1900-1910. GPU 1 bounds the period: 1400 ns."""
    r = run(frames=4)
    assert rows(r, "render.a") == [(0, 1000), (1400, 2400), (2800, 3800), (4200, 5200)]
    assert rows(r, "out.a.d2h", 0) == [(1000, 1200)] and rows(r, "out.a.h2d", 0) == [(1200, 1400)]
    assert rows(r, "out.b.d2h", 0) == [(1400, 1500)] and rows(r, "out.b.h2d", 0) == [(1500, 1600)]
    assert rows(r, "render.c", 0) == [(1600, 1900)]
    assert presents(r) == [1910, 3310, 4710, 6110]
    assert list(r.frames.latency_ns) == [1910] * 4
    assert r.config["bytes_per_frame"] == 300


def test_chunks_overlap_download_and_upload():
    r = run(frames=2, chunks=2)
    assert rows(r, "out.a#1.h2d", 0) == [(1200, 1300)]
    assert rows(r, "out.b#1.h2d", 0) == [(1500, 1550)]
    assert presents(r)[0] == 1860  # 50 ns less latency than whole copies


def test_frame_granularity_copies_once_after_gpu1():
    r = run(frames=2, copy_granularity="frame")
    assert rows(r, "out.d2h", 0) == [(1400, 1700)] and rows(r, "out.h2d", 0) == [(1700, 2000)]
    assert presents(r)[0] == 2310


def test_copies_on_graphics_queue_serialize_with_rendering():
    r = run(frames=6, copy_queue="graphics")
    assert rows(r, "out.a.d2h", 0) == [(1000, 1200)] and rows(r, "render.b", 0) == [(1200, 1600)]
    p = presents(r)
    assert p[5] - p[4] == 1700  # a + 200 + b + 100 on GPU 1, vs 1400 with a copy engine
    assert set(r.trace[r.trace.step.isin(["d2h", "h2d"])].engine) == {"graphics"}


def test_peer_link_one_copy_per_piece():
    r = run(frames=2, prof=profile(peer_gbps=2.0))
    assert rows(r, "out.a.p2p", 0) == [(1000, 1100)] and rows(r, "out.b.p2p", 0) == [(1400, 1450)]
    with pytest.raises(InputError, match="peer"):
        run(frames=2, path="peer")


def test_pipelining_improves_frame_time_not_latency():
    one = run(frames=20, gpus=1)
    two = run(frames=20)
    assert two.summary["frame_time_ms"] < one.summary["frame_time_ms"]
    assert two.summary["latency_ms"] >= one.summary["latency_ms"]


def test_split_beyond_passes_rejected():
    with pytest.raises(InputError, match="split_at"):
        run(split_at=4)


def test_20000_frames_no_drift():
    r = simulate(experiment(profile(gbps=7 / 3), "pipelining", PASSES, frames=20_000, split_at=2,
                            fif=3, chunks=3), record_trace=False)
    assert assert_no_drift(r.frames.present_ns) == 1


READS = [timed("a", 1000, output_bytes=200), timed("c", 300), timed("d", 200)]


def test_consumer_waits_reads_overlaps_arrival_with_gpu0_work():
    """a (1000 ns, 200 B out) on GPU 1; c (300) and d (200, reads a) on GPU 0.
    'all': c waits for a's arrival (d2h 1000-1200, h2d -1400): c 1400-1700, d -1900, present 1910.
    'reads': c runs at once (0-300) and only d waits: d 1400-1600, present 1610. In 2 chunks
    the last piece arrives at 1300 (d2h 1000-1100-1200, h2d 1100-1200-1300): d 1300-1500,
    present 1510; each piece's buffer is reused after frame f-2's d."""
    base = dict(split_at=1, frames=3)
    every = simulate(experiment(profile(), "pipelining", READS, fif=3, warmup=1, **base))
    assert rows(every, "render.c", 0) == [(1400, 1700)] and presents(every)[0] == 1910
    own = simulate(experiment(profile(), "pipelining", READS, fif=3, warmup=1,
                              consumer_waits="reads", reads={"d": ["a"]}, **base))
    assert rows(own, "render.c", 0) == [(0, 300)] and rows(own, "render.d", 0) == [(1400, 1600)]
    assert presents(own)[0] == 1610 and own.config["consumer_waits"] == "reads"
    chunked = simulate(experiment(profile(), "pipelining", READS, fif=3, warmup=1, chunks=2,
                                  consumer_waits="reads", reads={"d": ["a"]}, **base))
    assert rows(chunked, "out.a#1.h2d", 0) == [(1200, 1300)]
    assert rows(chunked, "render.d", 0) == [(1300, 1500)] and presents(chunked)[0] == 1510
    from mgpusim.schedules.program import build_program
    program = build_program(experiment(profile(), "pipelining", READS, split_at=1, chunks=2,
                                       consumer_waits="reads", reads={"d": ["a"]}))
    up = next(t for t in program.templates[0] if t.name == "out.a#0.h2d")
    assert ("render.d", -2) in [(d.task, d.offset) for d in up.deps]


def test_consumer_waits_unread_piece_arrives_before_present():
    """Nobody on GPU 0 reads a: c and d run at once (0-300-500), the present waits for a's
    arrival at 1400 (1400-1410)."""
    r = simulate(experiment(profile(), "pipelining", READS, split_at=1, frames=2, fif=3, warmup=1,
                            consumer_waits="reads"))
    assert rows(r, "render.d", 0) == [(300, 500)] and rows(r, "present", 0) == [(1400, 1410)]


@pytest.mark.parametrize("opts, field", [
    ({"reads": {"d": ["a"]}}, "schedule.reads"),
    ({"consumer_waits": "reads", "reads": {"a": ["a"]}}, "schedule.reads.a"),
    ({"consumer_waits": "reads", "reads": {"d": ["c"]}}, "schedule.reads.d"),
    ({"consumer_waits": "reads", "reads": {"d": "a"}}, "schedule.reads.d"),
    ({"consumer_waits": "some"}, "schedule.consumer_waits")])
def test_consumer_waits_bad_input(opts, field):
    from mgpusim.schedules.program import build_program
    with pytest.raises(InputError, match=field):
        build_program(experiment(profile(), "pipelining", READS, split_at=1, **opts))


def test_device_group_copies_go_gpu_to_gpu_over_pcie():
    """path = 'group' (a linked-node adapter / device group, no peer link in the profile):
    one copy per piece on GPU 1's copy engine, at the slower of GPU 1's d2h (4 B/ns) and
    GPU 0's h2d (2 B/ns): a's 200 B 1000-1100, b's 100 B 1400-1450; c 1450-1750, present 1760."""
    prof = profile([gpu(gbps=2.0), gpu(gbps=4.0)])
    r = run(frames=2, prof=prof, path="group")
    assert rows(r, "out.a.group", 0) == [(1000, 1100)] and rows(r, "out.b.group", 0) == [(1400, 1450)]
    assert set(r.trace[r.trace.task == "out.a.group"].device) == {"gpu1"}
    assert not r.trace.step.isin(["d2h", "h2d", "host_copy"]).any()
    assert presents(r)[0] == 1760
    assert presents(run(frames=6, prof=prof, path="group", fidelity="analytic")) == \
        presents(run(frames=6, prof=prof, path="group"))
    from mgpusim.schedules.program import build_program
    copy = next(t for t in build_program(experiment(prof, "pipelining", PASSES, split_at=2,
                                                     path="group")).templates[0]
                if t.name == "out.a.group")
    assert copy.path == "group" and copy.src is None  # left unbound: the runner refuses it


def test_reads_on_one_gpu_is_the_baseline():
    """The same file with gpus = 1: nothing crosses, `reads` is only checked for names."""
    kw = dict(split_at=1, frames=2, fif=3, warmup=1, gpus=1, consumer_waits="reads")
    r = simulate(experiment(profile(), "pipelining", READS, reads={"d": ["a"]}, **kw))
    assert presents(r)[0] == 1000 + 300 + 200 + 10
    with pytest.raises(InputError, match="schedule.reads.d"):
        simulate(experiment(profile(), "pipelining", READS, reads={"d": ["x"]}, **kw))


def test_producer_chunks_copy_each_piece_as_it_is_rendered():
    """Two chunks, each of GPU 1's passes in two halves: a#0 0-500, a#1 500-1000, b#0
    1000-1200, b#1 1200-1400. a's first 100 B leave at 500 (d2h 500-600, h2d 600-700), its
    second at 1000 (1000-1100-1200); b's 50 B pieces 1200-1250-1300 and 1400-1450-1500.
    c 1500-1800, present 1810: 50 ns less than chunks that leave after the whole pass."""
    r = run(frames=2, chunks=2, producer_chunks=True)
    assert rows(r, "render.a#0", 0) == [(0, 500)] and rows(r, "render.b#1", 0) == [(1200, 1400)]
    assert rows(r, "out.a#0.d2h", 0) == [(500, 600)] and rows(r, "out.a#0.h2d", 0) == [(600, 700)]
    assert rows(r, "out.b#0.h2d", 0) == [(1250, 1300)] and rows(r, "out.b#1.h2d", 0) == [(1450, 1500)]
    assert presents(r)[0] == 1810
    assert rows(r, "render.a#0", 1) == [(1400, 1900)]  # GPU 1 goes on with the next frame
    from mgpusim.schedules.program import build_program
    piece = next(t for t in build_program(experiment(profile(), "pipelining", PASSES, chunks=2,
                                                      producer_chunks=True)).templates[0]
                 if t.name == "render.a#1")
    assert "simulated only" in piece.params["unsupported"]
    with pytest.raises(InputError, match="schedule.producer_chunks"):
        run(frames=2, chunks=2, producer_chunks=True, copy_granularity="frame")


def test_consumer_chunks_each_piece_after_its_chunk():
    """d (200 ns, reads a) in two halves, each after its chunk of a: chunk 0 arrives at 1200
    (d2h 1000-1100, h2d 1100-1200), chunk 1 at 1300: d#0 1200-1300, d#1 1300-1400, present 1410
    (1510 when d waits for both). With producer_chunks too, a's halves leave at 500 and 1000:
    chunk 0 arrives at 700, chunk 1 at 1200: d#0 700-800, d#1 1200-1300, present 1310."""
    kw = dict(split_at=1, frames=2, fif=3, warmup=1, chunks=2, consumer_waits="reads",
              reads={"d": ["a"]}, consumer_chunks=True)
    r = simulate(experiment(profile(), "pipelining", READS, **kw))
    assert rows(r, "render.c", 0) == [(0, 300)]
    assert rows(r, "render.d#0", 0) == [(1200, 1300)] and rows(r, "render.d#1", 0) == [(1300, 1400)]
    assert presents(r)[0] == 1410
    both = simulate(experiment(profile(), "pipelining", READS, producer_chunks=True, **kw))
    assert rows(both, "render.d#0", 0) == [(700, 800)] and rows(both, "render.d#1", 0) == [(1200, 1300)]
    assert presents(both)[0] == 1310
    from mgpusim.schedules.program import build_program
    up = next(t for t in build_program(experiment(profile(), "pipelining", READS, **kw)).templates[0]
              if t.name == "out.a#1.h2d")
    assert ("render.d#1", -2) in [(d.task, d.offset) for d in up.deps]  # its reader frees it
    with pytest.raises(InputError, match="schedule.consumer_chunks"):
        build_program(experiment(profile(), "pipelining", READS, split_at=1, chunks=2,
                                 consumer_chunks=True))


def test_a_temporal_filter_reads_its_inputs_and_its_own_previous_frame():
    """A filter with one input more than the passes before it (TAA) samples them and, last, its
    own output of the previous frame: with consumer_waits = 'reads' it waits for what crossed
    (before, no source was found and only the present waited), and its image is bound
    double-buffered, the history read one frame back."""
    from mgpusim.schedules.pass_io import filter_sources
    from mgpusim.schedules.program import build_program
    passes = [timed("a", 1000, output_bytes=32), {"name": "taa", "kind": "filter", "inputs": 2,
                                                      "iterations": 10}]
    prof = profile()
    exp = experiment(prof, "pipelining", passes, split_at=1, consumer_waits="reads")
    assert filter_sources(exp.scene.passes, 1) == ["a", "taa"]
    program = build_program(exp)
    taa = next(t for t in program.templates[0] if t.name == "render.taa")
    assert "out.a.h2d" in [d.task for d in taa.deps]
    assert taa.reads == ("gpu0.in.a", "gpu0.pass.taa") and taa.params["read_offsets"] == (0, -1)
    assert next(r for r in program.resources if r.name == "gpu0.pass.taa").buffers == 2
    too_many = experiment(prof, "pipelining", [passes[0], {**passes[1], "inputs": 3}], split_at=1)
    taa = next(t for t in build_program(too_many).templates[0] if t.name == "render.taa")
    assert "1 come before it" in taa.params["unsupported"]
