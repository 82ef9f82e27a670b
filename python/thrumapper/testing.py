#
# SPDX-License-Identifier: GPL-3.0-or-later
#
"""Small helpers the QA tests share."""

import time


def wait_for(predicate, timeout_s=10.0, poll_s=0.01):
    """Poll until predicate() holds or timeout_s passes; return its last value.

    A flowgraph runs in its own threads: a test that posts a message (`_post`) or starts a
    flowgraph waits for the effect with this, never with a bare sleep.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()
