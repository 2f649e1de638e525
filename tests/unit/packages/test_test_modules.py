"""The test tree itself: pytest imports every test module by its basename (the test folders
are not packages), so two modules of one name anywhere under tests/ stop the whole run at
collection ("import file mismatch")."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parents[2]


def test_every_test_module_has_a_name_of_its_own():
    names = Counter(p.name for p in TESTS.rglob('test_*.py'))
    twice = {name: n for name, n in names.items() if n > 1}
    assert not twice, {
        name: sorted(str(p.relative_to(TESTS)) for p in TESTS.rglob(name)) for name in twice
    }
