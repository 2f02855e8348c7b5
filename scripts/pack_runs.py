"""Pack the committed measured runs under data/ into Parquet tables (or unpack them).

    python scripts/pack_runs.py                 # every runs folder under data/ that is not packed
    python scripts/pack_runs.py data/nvidia/h200_x2/runs_si
    python scripts/pack_runs.py --unpack data/nvidia/h200_x2/runs_si
    python scripts/pack_runs.py --logs data/nvidia/h200_x4      # its *.log into logs.parquet
    python scripts/pack_runs.py --tables                        # every measurements folder
    python scripts/pack_runs.py --tables data/nvidia/h200_x4/measurements

A runs folder is the folder a study or a `--runs` option names: the first three levels below
data/ (data/lavapipe/<job>/runs, data/nvidia/h200_x2/runs_si), or a run folder standing higher.
Each becomes runs.parquet + run_files.parquet (mgpusim.measure.run_archive); every file is
read back and compared before the originals are deleted. A folder of measured tables (a job's
`measurements/`: pass tables, their machine records, speed probes) packs the same way with
`--tables` (every file as text in run_files.parquet, runs.parquet empty).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from mgpusim.measure import run_archive

ROOT = Path(__file__).resolve().parents[1]


def runs_folders(data: Path) -> list[Path]:
    """The folders to pack under `data`: for every run, its ancestor three levels below data/
    (or the run folder itself where it stands higher)."""
    found = set()
    for run in run_archive.run_folders(data):
        parts = run.relative_to(data).parts
        found.add(data.joinpath(*parts[:3]) if len(parts) >= 3 else run)
    return sorted(found)


def table_folders(data: Path) -> list[Path]:
    """Every `measurements*` folder under `data` not packed yet that holds more files than the
    archive's two tables would."""
    return sorted(p for p in data.rglob("measurements*")
                  if p.is_dir() and not (p / run_archive.FILES).exists()
                  and len(run_archive.table_files(p)) > 2)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folders", nargs="*", type=Path, help="runs folders (default: all under data/)")
    p.add_argument("--unpack", action="store_true", help="write the files back instead")
    p.add_argument("--logs", action="store_true",
                   help="the folders' measuring logs (*.log) into logs.parquet instead of runs")
    p.add_argument("--tables", action="store_true",
                   help="folders of measured tables (default: every measurements folder under data/)")
    args = p.parse_args()
    if args.logs and not args.folders:
        p.error("--logs packs the folders given")
    if args.logs and args.tables:
        p.error("--logs and --tables pack different things: one at a time")
    folders = args.folders or (table_folders(ROOT / "data") if args.tables else runs_folders(ROOT / "data"))
    for folder in folders:
        if args.tables:
            n = run_archive.unpack(folder) if args.unpack else run_archive.pack_tables(folder)
        elif args.logs:
            n = run_archive.unpack_logs(folder) if args.unpack else run_archive.pack_logs(folder)
        else:
            n = run_archive.unpack(folder) if args.unpack else run_archive.pack(folder)
        print(f"{'unpacked' if args.unpack else 'packed'} {n:4d} files: {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
