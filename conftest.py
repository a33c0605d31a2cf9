"""The suite's order: the longest files first, so that pytest-xdist's workers (one file at a
time, ``--dist loadfile --no-loadscope-reorder``: xdist would otherwise hand out the files
with the most tests first, and every notebook, one test each, last) finish together instead
of one waiting on a long notebook.

``HEAVY`` lists the slowest files as measured by ``pytest --durations`` in the suite on 2
cores (2026-11-28: the video refinement test and the walk's full-body fit about 2 min each,
then notebooks 21, 15, 18, 14, ... at 40-70 s); the other notebooks come next, then the
other tests, each group in its own order. A file missing from the list only runs later;
nothing is skipped.
"""

HEAVY = ("test_rig_refinement", "test_walk_full_fit", "test_rom_fit", "21_", "15_", "18_", "14_",
         "17_", "13_", "01_", "03_", "08_", "test_walk_system", "20_", "07_", "test_full_fit",
         "test_systems", "19_", "test_cli")


def _rank(item) -> tuple:
    name = item.path.name
    for i, prefix in enumerate(HEAVY):
        if name.startswith(prefix):
            return (0, i)
    return (1, 0 if item.path.suffix == ".ipynb" else 1)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_rank)
