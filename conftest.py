"""The suite's order: the longest files first, so that pytest-xdist's workers (one file at a
time, ``--dist loadfile --no-loadscope-reorder``: xdist would otherwise hand out the files
with the most tests first, and every notebook, one test each, last) finish together instead
of one waiting on a long notebook.

``HEAVY`` lists the slowest files as measured by ``pytest --durations`` on 2 cores
(2026-11-27: notebook 20 about 6 min, 14 about 3 min, then 07, 15, the video refinement
test, ...); the other notebooks come next, then the other tests, each group in its own order.
A file missing from the list only runs later; nothing is skipped.
"""

HEAVY = ("20_", "test_rig_refinement", "14_", "07_", "15_", "test_full_fit", "18_", "01_",
         "03_", "08_", "17_", "test_systems", "13_", "19_", "21_")


def _rank(item) -> tuple:
    name = item.path.name
    for i, prefix in enumerate(HEAVY):
        if name.startswith(prefix):
            return (0, i)
    return (1, 0 if item.path.suffix == ".ipynb" else 1)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_rank)
