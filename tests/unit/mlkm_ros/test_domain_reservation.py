"""``mlkm_ros.domains.reserve_domain``: the domain id released last on this machine, by any
process, is the last one handed out again (a participant a finished holder left behind then
meets no new holder soon)."""

from __future__ import annotations

import os
import subprocess
import sys

from mlkm_ros import domains

PICK = 'from mlkm_ros.domains import reserve_domain\nwith reserve_domain() as d:\n    print(d)\n'


def _pick_in_another_process(lock_dir) -> int:
    env = {**os.environ, 'MLKM_DOMAIN_LOCK_DIR': str(lock_dir)}
    out = subprocess.run([sys.executable, '-c', PICK], env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return int(out.stdout)


def test_another_process_gets_the_id_released_longest_ago(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(domains, 'LOCK_DIR', tmp_path)
    # every id released once, 1 longest ago ... 100 last, and 37 after all of them
    for i in range(1, 101):
        lock = tmp_path / f'{i}.lock'
        lock.touch()
        os.utime(lock, ns=(0, (1000 if i == 37 else i) * 1_000_000_000))
    assert _pick_in_another_process(tmp_path) == 1
    # 1 is now the newest release: the next process takes 2, and 37 comes after 100
    assert _pick_in_another_process(tmp_path) == 2
    order = sorted(range(1, 101), key=lambda i: domains._released_at(tmp_path / f'{i}.lock'))
    assert order[:3] == [3, 4, 5] and order[-3:] == [37, 1, 2]


def test_a_held_id_is_skipped_and_an_id_never_held_comes_first(tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(domains, 'LOCK_DIR', tmp_path)
    for i in range(1, 101):
        (tmp_path / f'{i}.lock').touch()
    (tmp_path / '64.lock').unlink()  # never held
    with domains.reserve_domain() as first:
        assert first == 64
        # another process does not get the id this one holds, though it was never released
        got = _pick_in_another_process(tmp_path)
        assert got != 64
    assert domains._released_at(tmp_path / '64.lock') > 0
