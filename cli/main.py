"""Entry point of the ``starterbus`` command: parse (:mod:`starterbus.cli.parser`) and dispatch to the command's
own module, imported only now; a typed error is one line and exit 1.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from starterbus.cli.parser import Handler, command_module, parse_arguments


def _quiet_libraries(verbosity: int) -> None:
    """The libraries' own logs (pymodbus, asyncua, ...) only with ``-v``: cli/logs.py."""
    from starterbus.cli.logs import configure_logging

    configure_logging(verbosity)


def _stdout_closed() -> None:
    """The reader went away: what is still buffered goes nowhere, so Python's exit-time flush cannot fail."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def main(argv: Sequence[str] | None = None) -> int:
    from starterbus.core.errors import StarterbusError

    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list[:1] == ["__complete"]:  # the completion scripts' hidden helper: no command, never an error
        from starterbus.cli.completion_words import complete_main

        return complete_main(args_list[1:])
    try:
        args = parse_arguments(args_list)
        # after parsing: `--help` exits before, without importing logging
        _quiet_libraries(getattr(args, "log_level", 0))
        if getattr(args, "resolve_target", False):
            from starterbus.cli.target import resolve

            resolve(args)
        handler: Handler | str = args.handler
        if isinstance(handler, str):  # "module:function" in starterbus.cli, imported now
            module, _, function = handler.partition(":")
            handler = getattr(command_module(module), function)
            assert callable(handler)
        code = handler(args)
        sys.stdout.flush()  # a closed pipe shows here, not at exit (where Python prints a traceback, exit 120)
        return code
    except StarterbusError as exc:
        print(f"starterbus: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:  # output piped into `head` and the like: the reader has what it wanted
        _stdout_closed()
        return 0
    except SystemExit:  # --help, --version, a usage error: their output may meet a closed pipe too
        try:
            sys.stdout.flush()
        except BrokenPipeError:
            _stdout_closed()
        raise
    except OSError as exc:
        print(f"starterbus: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
