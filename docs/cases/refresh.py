"""Refresh the case pages: the predicted table of every docs/cases/<case>.md (between its
prediction markers), its comparison with the published figures (between its comparison
markers) and the timeline pictures docs/img/cases/<case>_<run>.png, from the same simulation
`mgpusim case <case>` runs. tests/test_cases.py checks that the pages' tables are current.

    PYTHONPATH=. python docs/cases/refresh.py
"""
from __future__ import annotations

from pathlib import Path

from mgpusim.cases.case_file import (COMPARISON, case_names, comparison_markdown, load_case, markdown,
                                   run_case, with_docs_block)
from mgpusim.commands.case import write_timelines

DOCS = Path(__file__).resolve().parent
IMAGES = DOCS.parent / "img" / "cases"


def main() -> None:
    IMAGES.mkdir(parents=True, exist_ok=True)
    for name in case_names():
        result = run_case(load_case(name))
        page = DOCS / f"{name}.md"
        text = with_docs_block(page.read_text(), markdown(result))
        if result.case.published:
            text = with_docs_block(text, comparison_markdown(result), COMPARISON)
        page.write_text(text)
        for path in write_timelines(result, IMAGES, f"{name}_"):
            print(path)
        print(page)


if __name__ == "__main__":
    main()
