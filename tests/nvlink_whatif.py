"""The NVLink what-if of a two-GPU study (docs/nvidia.md prints its table; a test checks it): the same configurations over peer-link-rate links.

The five-step schedule has no peer-copy route (steps 2 and 4 are a download and an upload over
each GPU's own link), so the what-if gives each GPU's link the peer link's bandwidth and
latency (the profile's first `peer_links` entry) and drops the host step (host_copy = false:
the contribution lands in memory the primary reads).
- `nvlink`: that, with the measured host dispatch between the two copies (Vulkan without
  device groups still synchronises the two devices on the host);
- `nvlink_groups`: also no host dispatch (device groups: cross-device semaphores).
"""
from __future__ import annotations

import copy
from dataclasses import replace
from pathlib import Path
from typing import Any

import pandas as pd

from mgpusim.model.profile import HardwareProfile, parse_profile
from mgpusim.model.toml_checks import read_toml
from mgpusim.sim.simulation import simulate
from mgpusim.studies.study_file import Study


def nvlink_profiles(profile: Path) -> dict[str, HardwareProfile]:
    """The measured profile and its two NVLink what-ifs."""
    data = read_toml(profile)
    peer = data["peer_links"][0]
    out = {"measured_links": parse_profile(copy.deepcopy(data), str(profile))}
    nv = copy.deepcopy(data)
    for gpu in nv["gpus"]:
        gpu["link"].update(h2d_gbps=peer["bandwidth_gbps"], d2h_gbps=peer["bandwidth_gbps"],
                           latency_ns=peer["latency_ns"])
        for fam in gpu.get("copy", {}).values():
            fam.pop("d2h_gbps", None)
            fam.pop("h2d_gbps", None)
    out["nvlink"] = parse_profile(copy.deepcopy(nv), str(profile) + " (NVLink what-if)")
    nv["host"]["dispatch_ns"] = 0
    out["nvlink_groups"] = parse_profile(nv, str(profile) + " (NVLink + device groups what-if)")
    return out


#: The schedules the what-if is made for: the five-step's download and upload over each GPU's
#: own link (the other schedules' copies run on paths of their own: what-ifs of their own)
FIVE_STEP = ("sort_first", "sort_last")


def nvlink_whatif(study: Study, extra: tuple[str, ...] = ()) -> pd.DataFrame:
    """Simulated frame time and latency of every held-out five-step configuration on several
    GPUs: as run (PCIe, the configuration's own host_copy), and over NVLink-rate links."""
    profiles = nvlink_profiles(study.profile)
    rows = []
    for e in study.held_out:
        schedule = e.load(study.profile).schedule
        if schedule.gpus < 2 or schedule.name not in FIVE_STEP:
            continue  # one GPU: nothing crosses; another schedule: not this what-if
        row: dict[str, Any] = {"config": e.name}
        for label, prof in profiles.items():
            sets = extra + (() if label == "measured_links" else ("schedule.host_copy=false",))
            exp = replace(e.load(study.profile, sets), profile=prof)
            s = simulate(exp, record_trace=False).summary
            row[f"{label}_frame_ms"] = s["frame_time_ms"]
            row[f"{label}_latency_ms"] = s["latency_ms"]
        rows.append(row)
    return pd.DataFrame(rows)
