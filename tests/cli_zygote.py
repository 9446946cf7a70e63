"""Runs ``motionaug`` command lines, each in a forked child of this one process, which imported the CLI and torch once.

A fresh ``motionaug`` process spends most of a failing command's seconds importing torch, and the error catalogue
runs dozens of such commands. A forked child runs the console script's own entry point (``app()``, as the
installed script's ``sys.exit(app())``) with its own working folder, argv, stdout and stderr files and exit status,
so its exit code, its lines and a traceback are what a user's process gives. Ray is not imported here: the CLI
imports it itself (an embedded Ray binds 127.0.0.1 only when the CLI imports it).

Protocol: one JSON request per stdin line, ``{"args": [...], "cwd": ..., "stdout": FILE, "stderr": FILE}``; the
answer is the child's exit code on its own stdout line. tests/test_error_catalogue.py starts it.
"""

from __future__ import annotations

import atexit
import json
import os
import sys
import traceback

import torch  # noqa: F401  (the import every command pays, paid once here)

from motionaug.workflows.cli import app


def _child(args: list[str], cwd: str, stdout: str, stderr: str) -> None:
    code = 1
    try:
        os.chdir(cwd)
        for fd, path, flags in ((0, os.devnull, os.O_RDONLY), (1, stdout, os.O_WRONLY), (2, stderr, os.O_WRONLY)):
            opened = os.open(path, flags | (os.O_CREAT | os.O_TRUNC if fd else 0), 0o644)
            os.dup2(opened, fd)
            os.close(opened)
        sys.argv = ["motionaug", *args]
        try:
            app()
            code = 0
        except SystemExit as done:  # what the interpreter does with ``sys.exit(app())``
            if done.code is None or isinstance(done.code, int):
                code = done.code or 0
            else:
                print(done.code, file=sys.stderr)
        except BaseException:  # noqa: BLE001 - an uncaught error: the traceback a user would see, exit 1
            traceback.print_exc()
        atexit._run_exitfuncs()  # e.g. Ray's shutdown, as at interpreter exit
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)


def main() -> None:
    for line in sys.stdin:
        request = json.loads(line)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:
            _child(request["args"], request["cwd"], request["stdout"], request["stderr"])
        _, status = os.waitpid(pid, 0)
        print(os.waitstatus_to_exitcode(status), flush=True)


if __name__ == "__main__":
    main()
