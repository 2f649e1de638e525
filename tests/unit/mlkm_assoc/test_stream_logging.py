"""The stream mode's threads log through one helper at several severities.

rclpy refuses a call site that logs at more than one severity; the stream mode's publisher
thread used one such call site and died with a traceback the first time it logged an error
after an info line (for example when the node stopped).
"""

from __future__ import annotations

import rclpy.logging

from mlkm_assoc.modes import leveled_log


def test_one_helper_logs_every_severity_in_any_order(capfd) -> None:
    log = leveled_log(rclpy.logging.get_logger('stream_logging_test'))
    log('info', 'first an info line')
    log('error', 'then an error line')
    log('warning', 'then a warning line')
    log('info', 'and info again')
    out, err = capfd.readouterr()
    text = out + err
    for line in ('first an info line', 'then an error line', 'then a warning line',
                 'and info again'):  # fmt: skip
        assert line in text, text
    assert 'ERROR' in text and 'WARN' in text
