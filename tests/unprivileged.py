"""Run a child process that the mode bits bind, so that permission tests check something under root (CI).

Root reads and writes through any mode bits (the capabilities CAP_DAC_OVERRIDE and
CAP_DAC_READ_SEARCH), so a test that makes a file unreadable proves nothing when it runs as root.
:func:`drop_privileges` gives the ``preexec_fn`` that removes both from the child's capability
bounding set before it executes its program: a root child then gets only the owner's bits of its
own files, as any user (its interpreter and the repository stay readable, unlike with a switch to
user ``nobody``, who may not enter root's home where the interpreter can live). When the tests do
not run as root, the mode bits bind already and nothing is changed.
"""

from __future__ import annotations

import ctypes
import os
from collections.abc import Callable

PR_CAPBSET_DROP = 24  # linux/prctl.h
CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH = 1, 2  # linux/capability.h


def _drop_file_access_capabilities() -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    for cap in (CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH):
        if libc.prctl(PR_CAPBSET_DROP, cap, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), f"prctl(PR_CAPBSET_DROP, {cap}) failed")


def drop_privileges() -> Callable[[], None] | None:
    """The ``preexec_fn`` of a child process that file modes bind; None when the tests are not root."""
    return _drop_file_access_capabilities if os.geteuid() == 0 else None
