"""The 4x H200 study (every schedule on a 4-GPU machine), offline: the committed tables and runs
(data/nvidia/h200_x4/, packed) give the committed profile again, held-out runs compare as
docs/nvidia_h200_x4.md says, and the copy tables hold the rows of GPUs copying at once."""
from __future__ import annotations

from mgpusim.validation.measured_check import read_table
from tests.study_helpers import ROOT, calibrated_and_committed, validate_held_out

STUDY = ROOT / "experiments" / "h200_x4" / "study.toml"
DATA = ROOT / "data" / "nvidia" / "h200_x4"


def test_the_committed_tables_and_runs_give_the_committed_profile(tmp_path):
    fitted, committed = calibrated_and_committed(STUDY, "h200_x4.toml", tmp_path)
    assert fitted["gpus"] == committed["gpus"] and fitted["host"] == committed["host"]
    assert committed["gpus"][0]["count"] == 4 and committed["gpus"][0]["name"] == "NVIDIA H200"
    assert "ns_per_particle_pixel" in committed["gpus"][0]["costs"]["particle_render"]


def test_held_out_particle_offload_and_pipelining_are_within_the_target(tmp_path):
    """Particle offload at 4x the calibrated particles on 4K (whose draw the particle_pixel term
    prices) and pipelining with 4 chunks at 4K, on two of the four GPUs."""
    for name in ("part4_2gpu_4k_p262k", "pipe4_2gpu_4k_chunks4"):
        summary = validate_held_out(STUDY, name, tmp_path)
        assert summary["measured_runs"] == 2  # the steady window of two interleaved runs
        assert abs(summary["frame_time_error"]) <= 0.05, (name, summary["frame_time_error"])
        assert abs(summary["replay_frame_time_error"]) <= 0.01, (name, summary["replay_frame_time_error"])


def test_the_copy_tables_hold_gpus_copying_at_once():
    """d2h and h2d were timed alone and with 2 and 4 GPUs copying at once (one row per GPU);
    four at once each get less than one alone (the host side of PCIe)."""
    for path in ("d2h", "h2d"):
        df = read_table(DATA / "measurements" / f"copy_{path}.csv")  # packed: read in place
        assert df.groupby("gpus")["gpu"].nunique().to_dict() == {1: 1, 2: 2, 4: 4}
        big = df[df["bytes"] == df["bytes"].max()]
        rate = (big["bytes"] / big["duration_ns"]).groupby(big["gpus"]).median()
        assert rate[4] < 0.9 * rate[1]
