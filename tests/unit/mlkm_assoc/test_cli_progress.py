"""``mlkm associate --progress``: the association's bar shows the fraction done and the time
left; warnings of any subcommand are one line."""

import io
import subprocess
import sys

import pytest

from mlkm_assoc import cli
from mlkm_assoc.cli_run import FractionBar, clock, fraction_line, remaining


def test_clock_and_time_left():
    assert [clock(s) for s in (0, 59.4, 61, 3599, 3600, 7384.6)] == [
        '00:00',
        '00:59',
        '01:01',
        '59:59',
        '1:00:00',
        '2:03:05',
    ]
    assert remaining(0.0, 10.0) is None
    assert remaining(0.25, 10.0) == pytest.approx(30.0)  # the average pace so far
    assert remaining(1.0, 10.0) == 0.0


def test_a_hand_made_sequence_of_fractions_on_a_fake_clock():
    now = [100.0]
    out = io.StringIO()
    bar = FractionBar('associating (x)', file=out, now=lambda: now[0])
    for t, f in ((2.0, 0.0), (4.0, 0.1), (10.0, 0.5), (12.0, 0.75), (13.0, 1.0)):
        now[0] = 100.0 + t
        bar.update(f)
    bar.close()
    lines = [line.rstrip() for line in out.getvalue().split('\r') if line.strip()]
    assert lines == [
        'associating (x): 00:00 elapsed',
        'associating (x): 00:02 elapsed',  # nothing reported yet: no fraction, no estimate
        'associating (x):  10%|##                  | 00:04 elapsed, 00:36 left',
        'associating (x):  50%|##########          | 00:10 elapsed, 00:10 left',
        'associating (x):  75%|###############     | 00:12 elapsed, 00:04 left',
        'associating (x): 100%|####################| 00:13 elapsed, 00:00 left',
    ]
    assert out.getvalue().endswith('\r' + ' ' * len(lines[-1]) + '\r')  # cleared at the end
    line = fraction_line('d', 0.5, 3725.0, width=4)
    assert line == 'd:  50%|##  | 1:02:05 elapsed, 1:02:05 left'


def test_associate_with_progress_shows_fraction_and_time_left(tmp_path, capsys):
    data = tmp_path / 'sim.csv'
    assert cli.main(['simulate', '--output', str(data), '--episodes', '2', '--seed', '2']) == 0
    argv = ['associate', '--input', str(data), '--output', str(tmp_path / 't.csv')]
    assert cli.main([*argv, '--method', 'assignment', '--progress']) == 0
    err = capsys.readouterr().err
    shown = [part.strip() for part in err.split('\r') if 'associating (assignment)' in part]
    fractions = [int(s.split(':')[1].split('%')[0]) for s in shown if '%' in s]
    assert fractions[-1] == 100 and fractions == sorted(fractions) and len(fractions) > 3
    assert all(s.endswith(' left') for s in shown if '%' in s)


#: A multiframe run whose local search is cut short (a budget of one candidate), through the
#: ``mlkm`` entry point in a process of its own: the warning the method really issues.
CUT_SHORT = """
import dataclasses, sys
import mlkm_core.associators as methods
@dataclasses.dataclass(frozen=True)
class CutShort(methods.AssociatorConfig):
    search_budget: int = 1
methods.AssociatorConfig = CutShort
from mlkm_assoc import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def test_a_warning_during_a_cli_run_is_one_line_without_a_path(tmp_path):
    data, tracks = tmp_path / 'sim.csv', tmp_path / 'tracks.csv'
    # more than multiframe.DUAL_START_MAX detections: one start, one warning
    argv = ['--episodes', '6', '--seed', '4', '--false-alarms-per-vehicle', '0.05']
    assert cli.main(['simulate', '--output', str(data), *argv]) == 0
    argv = ['associate', '--input', str(data), '--output', str(tracks), '--method', 'multiframe']
    run = subprocess.run(
        [sys.executable, '-c', CUT_SHORT, *argv], capture_output=True, text=True, timeout=300
    )
    assert run.returncode == 0, run.stderr
    assert run.stderr.splitlines() == [
        'mlkm associate: warning: multiframe: the local search from the kalman pass stopped at '
        'its budget of 1 candidates; the result is the best found within it',
    ]
    assert 'accuracy:' in run.stdout and tracks.exists()
