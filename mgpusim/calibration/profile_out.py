"""Write a calibration as a hardware profile (TOML) plus a fit report.

A lavapipe machine gets a complete profile made from the machine record (one queue per
simulated GPU, passes sharing the CPU cores); a real machine keeps a base profile's structure
(queues, links, memory, peer links) and replaces the fitted numbers.
"""
from __future__ import annotations

import copy
from typing import Any

import numpy as np

from mgpusim.calibration.fit import Fit
from mgpusim.calibration.overlap_fit import apply_overlap, overlap_line
from mgpusim.calibration.pass_fit import Calibration
from mgpusim.model.profile import parse_profile
from mgpusim.validation.measured_check import machine_of

DEFAULT_SIMULATED_GPUS = 4


def lavapipe_base(machine: dict[str, Any], gpus: int = DEFAULT_SIMULATED_GPUS) -> dict[str, Any]:
    """A skeleton profile of a lavapipe machine: every simulated GPU is CPU threads."""
    cores = int(machine.get("affinity_cpus") or machine.get("cpu_count") or 1)
    dev = (machine.get("gpus") or [{}])[0]
    threads = dev.get("lp_num_threads")
    gpu: dict[str, Any] = {
        "name": dev.get("device", "llvmpipe"), "count": gpus, "memory_bytes": 4 << 30,
        "queues": {"graphics": 1, "compute": 0, "transfer": 0},
        "link": {"pcie_gen": 3, "lanes": 16, "latency_ns": 0},
        "costs": {}, "copy": {},
    }
    if threads:
        gpu["cpu_threads"] = int(threads)
    return {
        "name": f"lavapipe on {machine.get('cpu', 'this CPU')} ({cores} cores)",
        "description": "CPU-emulated GPUs (Mesa lavapipe), one VkInstance each; fitted by mgpusim calibrate",
        "sources": {},
        "host": {"memory_bandwidth_gbps": 10.0, "memcpy_threads": cores, "memcpy_thread_gbps": 5.0,
                 "cpu_cores": cores, "gpus_share_cpu": True},
        "gpus": [gpu],
    }


def apply(cal: Calibration, base: dict[str, Any], command: str) -> dict[str, Any]:
    """Return `base` with the fitted coefficients put in every GPU entry and the host table."""
    out = copy.deepcopy(base)
    for gpu in out["gpus"]:
        costs = gpu.setdefault("costs", {})
        for kind, fit in cal.pass_fits.items():
            costs[kind] = cost_table(fit)
            if kind in cal.cores:
                costs[kind]["cores"] = round(cal.cores[kind][0], 3)
                if kind in cal.cores_method:
                    costs[kind]["cores_from_pairs"] = True
                if kind in cal.term_cores:
                    costs[kind]["term_cores"] = {t: round(c, 3) for t, c in cal.term_cores[kind].items()}
                overhead = cal.submission_cpu_ns.get(kind, 0.0)
                if overhead > 0:
                    costs[kind]["cpu_overhead_ns"] = round(overhead)
        if cal.copy_fits:
            _apply_copies(cal, gpu)
    if "present" not in out["gpus"][0].get("costs", {}):
        _estimate_present(cal, out)
    host = out.setdefault("host", {})
    for key in ("memory_bandwidth_gbps", "memcpy_thread_gbps"):
        if key in cal.host:
            host[key] = round(float(cal.host[key]), 4)
    if "host_copy_fixed_ns" in cal.host:
        host["host_copy_fixed_ns"] = int(round(cal.host["host_copy_fixed_ns"]))
    sources = out.setdefault("sources", {})
    overlap = apply_overlap(out, cal.overlap)
    if overlap and "queue_overlap" in out["gpus"][0]:
        sources["queue_overlap"] = (f"{overlap}; `mgpusim measure --pass overlap` fastest of the "
                                    "repetitions, median over sizes")
    elif overlap and overlap not in cal.warnings:
        cal.warnings.append(overlap)
    sources["calibration"] = (f"cost coefficients, copy rates and host copy rates fitted by `{command}` "
                              f"on {cal.machine.get('recorded_at', 'unknown date')} "
                              f"(machine: {cal.machine.get('cpu', '?')}, driver: {_driver(cal.machine)})")
    machine = machine_of(cal.machine)
    if machine is not None:  # where this profile's accuracy holds: validation compares it
        sources["machine"] = {"cpu": machine.cpu, "cpus": machine.cpus, "device": machine.device,
                              "driver": machine.driver}
    parse_profile(copy.deepcopy(out), "<calibrated profile>")  # what we write must load
    return out


def cost_table(fit: Fit) -> dict[str, Any]:
    """A pass kind's coefficients and, where finite, their standard errors (`stderr`), which
    simulate carries into results as a band."""
    table: dict[str, Any] = {name: _num(v) for name, v in zip(fit.names, fit.coef)}
    errors = {name: _num(e) for name, e in zip(fit.names, fit.stderr) if np.isfinite(e) and e > 0}
    if errors:
        table["stderr"] = errors
    return table


def _apply_copies(cal: Calibration, gpu: dict[str, Any]) -> None:
    """Link bandwidth per path = the fastest queue family the GPU has; a slower family gets a
    rate cap; each family's fixed cost is the median of its paths' fixed costs."""
    queues = gpu.get("queues", {})
    fits = {(p, q): f for (p, q), f in cal.copy_fits.items() if q == "graphics" or queues.get(q, 0) > 0}
    gbps = {key: (1.0 / f.coef[1] if f.coef[1] > 0 else 1e6) for key, f in fits.items()}
    best: dict[str, float] = {}
    for (path, _), rate in gbps.items():
        best[path] = max(best.get(path, 0.0), rate)
    copies: dict[str, Any] = {}
    for queue in sorted({q for _, q in fits}):
        fixed = [float(f.coef[0]) for (_, q), f in fits.items() if q == queue]
        copies[queue] = {"fixed_ns": int(round(float(np.median(fixed))))}
        for (path, q), rate in gbps.items():
            if q == queue and rate < 0.9 * best[path]:  # clearly slower than the path allows
                copies[queue][f"{path}_gbps"] = round(rate, 4)
    gpu["copy"] = copies
    link = gpu.setdefault("link", {})
    for path in ("h2d", "d2h"):
        if path in best:
            link[f"{path}_gbps"] = round(best[path], 4)
    if "d2d" in best:
        gpu["local_copy_gbps"] = round(best["d2d"], 4)


def _estimate_present(cal: Calibration, out: dict[str, Any]) -> None:
    """No present pass is measured: the runner's present is a copy of the colour frame into the
    displayed image, so it is costed as a device-local copy of 4 bytes per pixel (stated as
    derived in the sources)."""
    fit = cal.copy_fits.get(("d2d", "graphics"))
    if fit is None:
        return
    fixed, ns_per_byte = (float(c) for c in fit.coef)
    for gpu in out["gpus"]:
        gpu["costs"]["present"] = {"fixed_ns": _num(fixed), "ns_per_pixel": _num(4 * ns_per_byte)}
        if out["host"].get("gpus_share_cpu"):  # lavapipe copies in its queue thread: one core
            gpu["costs"]["present"]["cores"] = 1.0
    out["sources"]["present"] = ("derived: a present copies the RGBA8 frame, costed from the d2d "
                                 "copy fit (on lavapipe one core's work, as every copy)")


def report(cal: Calibration) -> str:
    """Each coefficient with its standard error, each fit's residuals, and the warnings."""
    lines = ["fit (value +- stderr; rel. rms residual; condition number)"]
    for kind, fit in cal.pass_fits.items():
        lines.append(f"  {kind}: " + ", ".join(f"{n}={_fmt(v, e)}" for n, v, e in zip(fit.names, fit.coef, fit.stderr))
                     + f"; rms {fit.rel_rms:.1%}; cond {fit.condition:.3g}")
    for (path, queue), fit in cal.copy_fits.items():
        bw = 1 / fit.coef[1] if fit.coef[1] > 0 else float("inf")
        lines.append(f"  copy {path} on {queue}: fixed_ns={_fmt(fit.coef[0], fit.stderr[0])}, "
                     f"{bw:.3g} GB/s; rms {fit.rel_rms:.1%}")
    for kind, (value, ratios) in cal.cores.items():
        method = cal.cores_method.get(kind, "slope of CPU time on pass time")
        split = "".join(f", {t}'s {c:.3g}" for t, c in cal.term_cores.get(kind, {}).items())
        lines.append(f"  {kind}: cores={value:.3g}{split} ({method}; submission "
                     f"{cal.submission_cpu_ns.get(kind, 0) / 1e3:.0f} us; per size: "
                     + ", ".join(f"{r:.2f}" for r in ratios) + ")")
    if cal.host:
        th = ", ".join(f"{k} thr: {v:.3g} GB/s" for k, v in cal.host.get("throughput_by_threads_gbps", {}).items())
        lines.append(f"  host copies: {th}")
    if cal.overlap:
        lines.append("  " + overlap_line(cal.overlap))
    lines += [f"warning: {w}" for w in cal.warnings]
    return "\n".join(lines)


def fit_details(cal: Calibration) -> dict[str, Any]:
    return {
        "passes": {k: {**f.as_dict(), "rel_rms": f.rel_rms, "condition": f.condition,
                       "rel_residuals": [float(x) for x in f.rel_residuals]} for k, f in cal.pass_fits.items()},
        "copies": {f"{p}/{q}": {**f.as_dict(), "rel_rms": f.rel_rms} for (p, q), f in cal.copy_fits.items()},
        "host": {k: v for k, v in cal.host.items()},
        "cores": {k: {"value": v, "ratios": r} for k, (v, r) in cal.cores.items()},
        "overlap": {k: {"value": v, "per_size": e} for k, (v, e) in cal.overlap.items()},
        "warnings": cal.warnings,
    }


def _fmt(value: float, err: float) -> str:
    return f"{value:.4g}" if not np.isfinite(err) else f"{value:.4g}+-{err:.2g}"


def _num(value: float) -> float:
    return float(f"{float(value):.6g}")


def _driver(machine: dict[str, Any]) -> str:
    gpus = machine.get("gpus") or [{}]
    return f"{gpus[0].get('driver', '?')} {gpus[0].get('driver_info', '')}".strip()

