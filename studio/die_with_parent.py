"""`python -I die_with_parent.py PARENT_PID -- PROGRAM ARG...`: ask the kernel to SIGTERM this process
when the thread that started it dies, then become PROGRAM (exec: same pid, so a stop, the process group
and a restarted server's adoption see the program itself).

The server starts its children through this script rather than a `preexec_fn`: Python code run between
fork and exec in a server with many threads can deadlock on a lock another thread held at the fork
(CPython's subprocess documentation warns of it). Run by path in isolated mode, it imports neither the
project nor anything beside it.
"""

import ctypes
import os
import signal
import sys

PR_SET_PDEATHSIG = 1


def main(argv: list[str]) -> None:
    if len(argv) < 3 or argv[1] != "--":
        sys.stderr.write("usage: die_with_parent.py PARENT_PID -- PROGRAM [ARG...]\n")
        sys.exit(2)
    parent_pid, program = int(argv[0]), argv[2:]
    if sys.platform.startswith("linux"):
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, int(signal.SIGTERM), 0, 0, 0)
        if os.getppid() != parent_pid:  # the server died before the call above took effect
            sys.exit(1)
    try:
        os.execvp(program[0], program)
    except OSError as e:
        sys.stderr.write(f"error: cannot run {program[0]}: {e}\n")
        sys.exit(127)


if __name__ == "__main__":
    main(sys.argv[1:])
