"""The 4x H100 study (five-step on 3 and 4 GPUs, AFR and XR on 4), offline: the committed tables
and runs (data/nvidia/h100_x4/, packed) give the committed profile again, held-out runs compare
as docs/nvidia_h100_x4.md says, and the copy table holds the rows of GPUs copying at once."""
from __future__ import annotations

from mgpusim.validation.measured_check import read_table
from tests.study_helpers import ROOT, calibrated_and_committed, validate_held_out

STUDY = ROOT / "experiments" / "h100_x4" / "study.toml"
DATA = ROOT / "data" / "nvidia" / "h100_x4"


def test_the_committed_tables_and_runs_give_the_committed_profile(tmp_path):
    fitted, committed = calibrated_and_committed(STUDY, "h100_x4.toml", tmp_path)
    assert fitted["gpus"] == committed["gpus"] and fitted["host"] == committed["host"]
    assert committed["gpus"][0]["count"] == 4


def test_held_out_five_step_runs_on_four_gpus_are_within_the_target(tmp_path):
    """A sort-last and a sort-first run on 4 GPUs, sizes the calibration never saw."""
    for name in ("sl4_portrait_t10M", "sf4_4k_it2000"):
        summary = validate_held_out(STUDY, name, tmp_path)
        assert summary["measured_runs"] == 2  # the steady window of two interleaved runs
        assert abs(summary["frame_time_error"]) <= 0.03, (name, summary["frame_time_error"])


def test_xr_strong_on_four_gpus_compares_with_the_present_on_the_one_graphics_queue(tmp_path):
    """The runner opens one VkQueue per family, so XR's present shares GPU 0's graphics queue
    with its rendering; the comparison finds that in the run's trace and models the run so
    (`queues_as_run`), and then strong scaling with 3 frames in flight is within the target."""
    summary = validate_held_out(STUDY, "xrs4_quest3_t3M_fif3", tmp_path)
    assert summary["queues_as_run"] == {"gpu0.graphics#1": "gpu0.graphics"}
    assert abs(summary["frame_time_error"]) <= 0.03, summary["frame_time_error"]


def test_the_copy_tables_hold_gpus_copying_at_once():
    """d2h and h2d were timed alone and with 2 and 4 GPUs copying at once (one row per GPU);
    the profile's link rates come from the rows of one GPU alone."""
    for path in ("d2h", "h2d"):
        df = read_table(DATA / "measurements" / f"copy_{path}.csv")  # packed: read in place
        counts = df.groupby("gpus")["gpu"].nunique().to_dict()
        assert counts == {1: 1, 2: 2, 4: 4}
