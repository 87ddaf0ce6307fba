"""Run a command under a seccomp filter that makes the named system calls fail with EPERM.

    python tests/seccomp_exec.py SYSCALL[,SYSCALL...] -- COMMAND...

A test helper standing in for the unit's SystemCallFilter= where systemd is not
PID 1: libseccomp (the library systemd itself uses) through ctypes; the filter
is inherited by COMMAND across exec. Calls unknown on this architecture are
skipped. Exits 3 if the filter cannot be loaded.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import sys

SCMP_ACT_ALLOW = 0x7FFF0000
SCMP_ACT_ERRNO = 0x00050000


def main(argv: list[str]) -> int:
    names, sep, *command = argv
    if sep != "--" or not command:
        print(__doc__, file=sys.stderr)
        return 2
    library = ctypes.util.find_library("seccomp")
    if library is None:
        print("seccomp_exec: libseccomp not found", file=sys.stderr)
        return 3
    lib = ctypes.CDLL(library)
    lib.seccomp_init.restype = ctypes.c_void_p
    lib.seccomp_init.argtypes = [ctypes.c_uint32]
    lib.seccomp_rule_add.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_int, ctypes.c_uint]
    lib.seccomp_load.argtypes = [ctypes.c_void_p]
    ctx = lib.seccomp_init(SCMP_ACT_ALLOW)
    denied = 0
    for name in names.split(","):
        nr = lib.seccomp_syscall_resolve_name(name.encode())
        if nr < 0:
            continue  # not a call on this architecture
        if lib.seccomp_rule_add(ctx, SCMP_ACT_ERRNO | errno.EPERM, nr, 0) == 0:
            denied += 1
    if lib.seccomp_load(ctx) != 0:
        print("seccomp_exec: could not load the filter", file=sys.stderr)
        return 3
    print(f"seccomp_exec: {denied} system calls denied", file=sys.stderr)
    os.execvp(command[0], command)  # replaces this process; raises OSError if it cannot
    return 127


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
