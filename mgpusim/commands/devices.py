"""`mgpusim devices`: the Vulkan devices, their queue families, timestamps and extensions."""
from __future__ import annotations

import argparse

from mgpusim.real.vulkan.instance import EXT_CALIBRATED, EXT_HOST_MEMORY, Instance

_FLAGS = {1: "graphics", 2: "compute", 4: "transfer", 8: "sparse", 16: "protected",
          32: "video_decode", 64: "video_encode", 256: "optical_flow"}


def _flags(value: int) -> str:
    return "|".join(name for bit, name in _FLAGS.items() if value & bit) or hex(value)


def run(args: argparse.Namespace) -> int:
    inst = Instance(validation=False)
    try:
        for dev in inst.devices:
            print(f"[{dev.index}] {dev.name} ({dev.device_type})")
            print(f"    driver: {dev.driver_name} {dev.driver_info} (version {dev.driver_version},"
                  f" Vulkan {dev.api_version})")
            print(f"    timestamp period: {dev.timestamp_period:g} ns")
            for fam in dev.queue_families:
                ts = f"{fam.timestamp_valid_bits}-bit timestamps" if fam.timestamp_valid_bits \
                    else "no timestamps"
                print(f"    queue family {fam.index}: {_flags(fam.flags)} x{fam.count}, {ts}"
                      f"  -> {fam.kind}")
            for ext in (EXT_HOST_MEMORY, *EXT_CALIBRATED):
                print(f"    {ext}: {'yes' if ext in dev.extensions else 'no'}")
    finally:
        inst.close()
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("devices", help="list Vulkan devices, queues and extensions",
                                   description=__doc__)
    parser.set_defaults(func=run)
